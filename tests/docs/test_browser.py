"""The manual and a report in a real browser: Debian's headless Chromium, driven by Playwright (the driver
the live view's test uses too) through its executable path, never a browser of Playwright's own
(`make browser` installs Debian's chromium; `.ci/run` runs it before `make test`).

The manual is built once (`mkdocs build --strict`, its own checks first: no warning, the pages where they
are expected) and opened twice, from disk (`file://.../index.html`, as
the README says) and served over http (Python's http.server on loopback). Each time every page the
navigation lists is loaded, and the test fails on

- a dead link: a navigation or page link to a file that is not there, a page that is not a page of
  the manual (a directory listing, a 404), an anchor the target page lacks;
- a console error (a script or a file that fails to load, a JavaScript exception, a request that
  fails);
- an image that does not load (not complete, or no pixels);
- a search without results: words typed into the search box must list pages;
- maths not rendered: the physics page's equations must be KaTeX, with no KaTeX error.

A comparison report (`fabric_optics.write_report` of the analytic fixtures) gets the same checks of
console, images and anchors. Without Chromium the test fails and says how to install it: it is never
skipped.
"""

from __future__ import annotations

import functools
import http.server
import os
import subprocess
import sys
import threading
import time
from pathlib import Path
from urllib.parse import unquote, urldefrag, urlparse

import pytest

ROOT = Path(__file__).resolve().parents[2]
CHROMIUM = Path("/usr/bin/chromium")
#: the flags Debian's chromium runs headless with here (no network of its own, no GPU); Playwright adds
#: --headless itself
FLAGS = ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run", "--disable-background-networking",
         "--disable-component-update", "--disable-sync"]
#: words typed into the search box, each expected to find pages
SEARCH_WORDS = ("goniophotometer", "normalisation")


def _missing_browser() -> str | None:
    """Why the browser cannot start (and how to install it), or None."""
    if CHROMIUM.is_file():
        return None
    return (f"no {CHROMIUM}: the browser test needs Debian's chromium; `make browser` installs it "
            "(apt-get, as root)")


def test_a_missing_browser_fails_and_says_how_to_install_it(monkeypatch, tmp_path):
    monkeypatch.setattr(sys.modules[__name__], "CHROMIUM", tmp_path / "no-chromium")
    why = _missing_browser()
    assert why is not None and "`make browser` installs it" in why and str(tmp_path / "no-chromium") in why


class Browser:
    """One page of headless Chromium and what went wrong on it since :meth:`problems` was last read."""

    def __init__(self, page):
        self.page = page
        self._messages: list[str] = []
        # a file that fails to load is reported below with its address, by the response or the failed
        # request; the console's own line about it ("Failed to load resource: ...") names none
        page.on("console", lambda m: m.type == "error" and not m.text.startswith("Failed to load resource")
                and self._messages.append(m.text))
        page.on("pageerror", lambda e: self._messages.append(f"page error: {e}"))
        page.on("response", lambda r: r.status >= 400 and self._messages.append(f"HTTP {r.status}: {r.url}"))
        # a request cut off by the next navigation (net::ERR_ABORTED) is no failure of the page
        page.on("requestfailed", lambda r: "ERR_ABORTED" not in (r.failure or "")
                and self._messages.append(f"request failed: {r.url} {r.failure}"))

    def get(self, url: str) -> None:
        self.page.goto(url, timeout=60_000)

    def js(self, expression: str, arg=None):
        return self.page.evaluate(expression, arg)

    def count(self, selector: str) -> int:
        return self.page.locator(selector).count()

    def problems(self) -> list[str]:
        """The console errors, page errors and failed requests since the last call (a browser asks a server
        for /favicon.ico by itself; a report served alone has none)."""
        out = [m for m in self._messages if "favicon.ico" not in m]
        self._messages.clear()
        return out


@pytest.fixture(scope="module")
def browser():
    why = _missing_browser()
    if why:
        pytest.fail(why, pytrace=False)
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        pytest.fail("playwright is missing: `pip install -e '.[test]'` (it drives Debian's chromium, installed by "
                    "`make browser`)", pytrace=False)
    with sync_playwright() as pw:
        chromium = pw.chromium.launch(executable_path=str(CHROMIUM), args=FLAGS)
        try:
            yield Browser(chromium.new_page(viewport={"width": 1280, "height": 900}))
        finally:
            chromium.close()


@pytest.fixture(scope="module")
def built(tmp_path_factory) -> tuple[Path, subprocess.CompletedProcess]:
    """The manual built once (`mkdocs build --strict`) for the build's own checks and the browser's: the site
    folder and the build's run (its return code and log)."""
    out = tmp_path_factory.mktemp("site") / "site"
    run = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(out)], cwd=ROOT,
                         capture_output=True, text=True, env={**os.environ, "NO_MKDOCS_2_WARNING": "1"})
    return out, run


@pytest.fixture(scope="module")
def site(built) -> Path:
    out, run = built
    assert run.returncode == 0, (run.stdout + run.stderr)[-3000:]
    return out


@pytest.mark.timeout(900)
def test_the_manual_builds_in_strict_mode(built):
    """`make test` builds the manual: `mkdocs build --strict` must succeed with no warning (a broken link, a page
    missing from the navigation, an unresolved docstring reference); the pages are where the browser checks
    below and the README expect them."""
    site, run = built
    log = run.stdout + run.stderr
    assert run.returncode == 0, f"mkdocs build --strict failed:\n{log[-4000:]}"
    warnings = [line for line in log.splitlines() if line.startswith("WARNING")]
    assert not warnings, "\n".join(warnings)
    # pages are files, not folders (use_directory_urls: false): the site works opened from disk
    for page in ("index.html", "tutorials/mock-lab.html", "reference/cli.html", "reference/config.html",
                 "reference/plans.html", "reference/api.html", "explanation/felt-note.html"):
        assert (site / page).is_file(), f"the site has no {page}"
    # search from disk: the index inlined into a script, the worker shim served from the site itself
    assert (site / "search" / "search_index.js").read_text(encoding="utf-8").startswith("var __index = ")
    index = (site / "index.html").read_text(encoding="utf-8")
    assert "assets/iframe-worker/shim.js" in index and "unpkg.com" not in index
    assert "fonts.googleapis.com" not in index
    # the maths of the physics page: KaTeX delimiters for the bundled copy (rendered in the browser below)
    physics = (site / "physics.html").read_text(encoding="utf-8")
    assert physics.count('class="arithmatex"') >= 10 and (site / "assets/katex/katex.min.js").is_file()
    api = (site / "reference/api.html").read_text(encoding="utf-8")
    assert "read_dataset" in api and "Read and validate the dataset" in api   # mkdocstrings rendered it
    assert "measure_on_mock" in api and "simulate" in api


@pytest.fixture(scope="module")
def report(tmp_path_factory) -> Path:
    import fabric_optics as fo

    out = tmp_path_factory.mktemp("report") / "report"
    fo.write_report(ROOT / "fixtures" / "analytic" / "measured_red", ROOT / "fixtures" / "analytic" / "sim_lambert",
                    out=out)
    return out


class _Quiet(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args):      # no request lines in the test's output
        pass


@pytest.fixture(scope="module")
def serve():
    """serve(folder) -> the http URL of the folder, served on loopback until the module ends."""
    servers = []

    def _serve(folder: Path) -> str:
        server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), functools.partial(_Quiet, directory=str(folder)))
        threading.Thread(target=server.serve_forever, daemon=True).start()
        servers.append(server)
        return f"http://127.0.0.1:{server.server_address[1]}/"
    yield _serve
    for server in servers:
        server.shutdown()
        server.server_close()


def _broken_images(browser: Browser) -> list[str]:
    return browser.js("Array.from(document.images).filter(i => !i.complete || i.naturalWidth === 0)"
                      ".map(i => i.getAttribute('src').slice(0, 80))")


def _links(browser: Browser, selector: str) -> list[str]:
    return browser.js("s => Array.from(document.querySelectorAll(s)).map(a => a.href)", selector)


def _target_exists(url: str, base: str, folder: Path) -> bool:
    """A link inside the site: its file exists (a folder is not a page; it would be a directory listing)."""
    path = unquote(urlparse(urldefrag(url)[0]).path)
    rel = path[len(unquote(urlparse(base).path)):]
    target = folder / rel
    return target.is_file()


def _wait(predicate, timeout: float = 10.0):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        value = predicate()
        if value:
            return value
        time.sleep(0.1)
    return predicate()


def _check_site(browser: Browser, site: Path, base: str) -> dict:
    """Every page of the navigation loaded and checked; returns the figures (and asserts nothing itself)."""
    problems: list[str] = []
    browser.get(base + "index.html")
    problems += [f"index.html: console: {m}" for m in browser.problems()]
    nav = sorted({urldefrag(u)[0] for u in _links(browser, "nav.md-nav--primary a.md-nav__link[href]")})
    pages = links = images = 0
    anchors_wanted: dict[str, set[str]] = {}
    for url in nav:
        if not url.startswith(base):
            problems.append(f"navigation link outside the site: {url}")
            continue
        if not _target_exists(url, base, site):
            problems.append(f"dead navigation link: {url}")
            continue
        browser.get(url)
        pages += 1
        if not browser.count("article.md-content__inner"):
            problems.append(f"{url}: not a page of the manual ({browser.page.title()!r})")
        problems += [f"{url}: image does not load: {src}" for src in _broken_images(browser)]
        images += browser.js("document.images.length")
        problems += [f"{url}: console: {m}" for m in browser.problems()]
        for link in _links(browser, "article a[href]"):
            if not link.startswith(base):
                continue            # external addresses are not followed offline
            links += 1
            page, anchor = urldefrag(link)
            if not _target_exists(page, base, site):
                problems.append(f"{url}: dead link {link}")
            elif anchor:
                anchors_wanted.setdefault(page, set()).add(anchor)
    for page, anchors in anchors_wanted.items():
        html = (site / unquote(urlparse(page).path)[len(unquote(urlparse(base).path)):]).read_text(encoding="utf-8")
        problems += [f"dead anchor {page}#{a}" for a in sorted(anchors) if f'id="{a}"' not in html]
    # search: the box finds pages for each word
    results = {}
    browser.get(base + "index.html")
    for word in SEARCH_WORDS:
        box = browser.page.locator("input.md-search__input")
        if not box.is_visible():        # a narrow window: the search opens from its button
            browser.page.locator("label.md-header__button[for='__search']").click()
        box.click()
        box.fill("")
        box.press_sequentially(word)    # typed key by key, as a reader types
        results[word] = _wait(lambda: browser.count(".md-search-result__item"))
        browser.get(base + "index.html")
    problems += [f"search for {w!r}: no results" for w, n in results.items() if not n]
    # maths: the physics page's equations rendered by KaTeX
    browser.get(base + "physics.html")
    katex = _wait(lambda: browser.count(".katex"))
    katex_errors = browser.count(".katex-error")
    if katex < 10 or katex_errors:
        problems.append(f"physics.html: {katex} formulas rendered, {katex_errors} KaTeX errors")
    problems += [f"search/maths: console: {m}" for m in browser.problems()]
    return {"problems": problems, "pages": pages, "links": links, "images": images, "search": results,
            "formulas": katex}


def test_the_manual_works_opened_from_disk(browser, site):
    figures = _check_site(browser, site, site.as_uri() + "/")
    assert not figures["problems"], "\n".join(figures["problems"][:30])
    assert figures["pages"] >= 35 and figures["links"] > 100 and figures["images"] >= 5, figures
    print(f"from disk: {figures}")


def test_the_manual_works_served_over_http(browser, site, serve):
    figures = _check_site(browser, site, serve(site))
    assert not figures["problems"], "\n".join(figures["problems"][:30])
    assert figures["pages"] >= 35, figures
    print(f"served: {figures}")


@pytest.mark.parametrize("how", ["disk", "http"])
def test_a_report_shows_every_figure_without_errors(browser, report, serve, how):
    url = (report / "report.html").as_uri() if how == "disk" else serve(report) + "report.html"
    browser.problems()
    browser.get(url)
    assert browser.count("h1"), browser.page.title()
    images = browser.js("document.images.length")
    assert images >= 5 and not _broken_images(browser)
    assert not browser.problems()
    anchors = [urldefrag(u)[1] for u in _links(browser, "a[href^='#']")]
    missing = [a for a in anchors if not browser.js("a => !!document.getElementById(a)", a)]
    assert not missing, missing
    # the page names what wrote it
    assert "Written by fabric-optics" in browser.page.locator("footer").inner_text()


@pytest.mark.parametrize("how", ["disk", "http"])
def test_the_checks_see_a_missing_file_a_script_error_and_a_broken_image(browser, serve, tmp_path, how):
    """What the checks above rely on: a page with a missing stylesheet, a failing script and a missing image
    yields a problem naming each, and the image counts as broken."""
    (tmp_path / "bad.html").write_text("<!doctype html><html><head><link rel='stylesheet' href='gone.css'></head>"
                                       "<body><img src='gone.png'><script>undefinedFunction()</script></body></html>",
                                       encoding="utf-8")
    url = (tmp_path / "bad.html").as_uri() if how == "disk" else serve(tmp_path) + "bad.html"
    browser.problems()
    browser.get(url)
    problems = "\n".join(browser.problems())
    assert "gone.css" in problems and "gone.png" in problems and "undefinedFunction" in problems, problems
    assert _broken_images(browser) == ["gone.png"]
