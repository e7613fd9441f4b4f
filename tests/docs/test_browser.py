"""The manual and a report in a real browser: Debian's headless Chromium, driven by Selenium through its
chromedriver (`make browser` installs both; `.ci/run` runs it before `make test`).

The manual is built (`mkdocs build --strict`) and opened twice, from disk (`file://.../index.html`, as
the README says) and served over http (Python's http.server on loopback). Each time every page the
navigation lists is loaded, and the test fails on

- a dead link: a navigation or page link to a file that is not there, a page that is not a page of
  the manual (a directory listing, a 404), an anchor the target page lacks;
- a console error (a script or a file that fails to load, a JavaScript exception);
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
CHROMIUM, CHROMEDRIVER = Path("/usr/bin/chromium"), Path("/usr/bin/chromedriver")
FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--window-size=1280,900")
#: words typed into the search box, each expected to find pages
SEARCH_WORDS = ("goniophotometer", "normalisation")


def _missing_browser() -> str | None:
    """Why the browser cannot start (and how to install it), or None."""
    missing = [str(p) for p in (CHROMIUM, CHROMEDRIVER) if not p.is_file()]
    if not missing:
        return None
    return (f"no {' and no '.join(missing)}: the browser test needs Debian's chromium and chromium-driver; "
            "`make browser` installs them (apt-get, as root)")


def test_a_missing_browser_fails_and_says_how_to_install_it(monkeypatch, tmp_path):
    monkeypatch.setattr(sys.modules[__name__], "CHROMIUM", tmp_path / "no-chromium")
    assert "`make browser` installs them" in _missing_browser() and str(tmp_path / "no-chromium") in _missing_browser()


@pytest.fixture(scope="module")
def browser(tmp_path_factory):
    why = _missing_browser()
    if why:
        pytest.fail(why, pytrace=False)
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = str(CHROMIUM)
    for flag in FLAGS + (f"--user-data-dir={tmp_path_factory.mktemp('chromium-profile')}",):
        options.add_argument(flag)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    driver = webdriver.Chrome(options=options, service=Service(str(CHROMEDRIVER)))
    driver.set_page_load_timeout(60)
    yield driver
    driver.quit()


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("site") / "site"
    run = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(out)], cwd=ROOT,
                         capture_output=True, text=True, env={**os.environ, "NO_MKDOCS_2_WARNING": "1"})
    assert run.returncode == 0, run.stderr[-3000:]
    return out


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


def _console_errors(driver) -> list[str]:
    # a browser asks a server for /favicon.ico by itself; a report served alone has none
    return [e["message"] for e in driver.get_log("browser")
            if e["level"] == "SEVERE" and "favicon.ico" not in e["message"]]


def _broken_images(driver) -> list[str]:
    return driver.execute_script(
        "return Array.from(document.images).filter(i => !i.complete || i.naturalWidth === 0)"
        ".map(i => i.getAttribute('src').slice(0, 80))")


def _links(driver, selector: str) -> list[str]:
    return driver.execute_script(f"return Array.from(document.querySelectorAll({selector!r})).map(a => a.href)")


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


def _check_site(driver, site: Path, base: str) -> dict:
    """Every page of the navigation loaded and checked; returns the figures (and asserts nothing itself)."""
    problems: list[str] = []
    driver.get(base + "index.html")
    driver.get_log("browser")
    nav = sorted({urldefrag(u)[0] for u in _links(driver, "nav.md-nav--primary a.md-nav__link[href]")})
    pages = links = images = 0
    anchors_wanted: dict[str, set[str]] = {}
    for url in nav:
        if not url.startswith(base):
            problems.append(f"navigation link outside the site: {url}")
            continue
        if not _target_exists(url, base, site):
            problems.append(f"dead navigation link: {url}")
            continue
        driver.get(url)
        pages += 1
        if not driver.find_elements("css selector", "article.md-content__inner"):
            problems.append(f"{url}: not a page of the manual ({driver.title!r})")
        problems += [f"{url}: image does not load: {src}" for src in _broken_images(driver)]
        images += driver.execute_script("return document.images.length")
        problems += [f"{url}: console: {m}" for m in _console_errors(driver)]
        for link in _links(driver, "article a[href]"):
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
    driver.get(base + "index.html")
    for word in SEARCH_WORDS:
        box = driver.find_element("css selector", "input.md-search__input")
        if not box.is_displayed():      # a narrow window: the search opens from its button
            driver.find_element("css selector", "label.md-header__button[for='__search']").click()
        box.click()
        box.clear()
        box.send_keys(word)
        results[word] = _wait(lambda: len(driver.find_elements("css selector", ".md-search-result__item")))
        driver.get(base + "index.html")
    problems += [f"search for {w!r}: no results" for w, n in results.items() if not n]
    # maths: the physics page's equations rendered by KaTeX
    driver.get(base + "physics.html")
    katex = _wait(lambda: driver.execute_script("return document.querySelectorAll('.katex').length"))
    katex_errors = driver.execute_script("return document.querySelectorAll('.katex-error').length")
    if katex < 10 or katex_errors:
        problems.append(f"physics.html: {katex} formulas rendered, {katex_errors} KaTeX errors")
    problems += [f"search/maths: console: {m}" for m in _console_errors(driver)]
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
    browser.get(url)
    assert browser.find_elements("css selector", "h1"), browser.title
    images = browser.execute_script("return document.images.length")
    assert images >= 5 and not _broken_images(browser)
    assert not _console_errors(browser)
    anchors = [urldefrag(u)[1] for u in _links(browser, "a[href^='#']")]
    missing = [a for a in anchors if not browser.execute_script("return !!document.getElementById(arguments[0])", a)]
    assert not missing, missing
    # the page names what wrote it
    assert "Written by fabric-optics" in browser.find_element("css selector", "footer").text
