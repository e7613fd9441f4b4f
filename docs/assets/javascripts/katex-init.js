// Render the maths of the page (pymdownx.arithmatex, generic mode) with the KaTeX copy in assets/katex/.
// Material's document$ emits once per page (and on each instant navigation); DOMContentLoaded otherwise.
(function () {
  function render(root) {
    renderMathInElement(root, {
      delimiters: [
        { left: "$$", right: "$$", display: true },
        { left: "$", right: "$", display: false },
        { left: "\\(", right: "\\)", display: false },
        { left: "\\[", right: "\\]", display: true }
      ],
      throwOnError: false
    });
  }
  if (typeof document$ !== "undefined") {
    document$.subscribe(function (doc) { render(doc.body); });
  } else {
    document.addEventListener("DOMContentLoaded", function () { render(document.body); });
  }
})();
