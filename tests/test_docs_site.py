"""The documentation site in a real browser (headless Chromium): the home page, the API page of
``gsjax.raster.render`` and a tutorial load with no console error, no request outside the site and the tutorial's
figures drawn (``make docs``; ``make test``'s quick build runs no tutorial and stamps the site so); the method page's
formulas are MathML that the browser lays out itself; the docstrings' Sphinx roles are cross-references. Uses
``site/`` as ``make docs`` or ``make docs-quick`` builds it (``make test`` builds it first)."""

from __future__ import annotations

import functools
import http.server
import re
import threading
from pathlib import Path

import pytest

from gsjax.viewer.browser import chromium_path, launch, open_page

SITE = Path(__file__).resolve().parents[1] / "site"


@pytest.fixture(scope="module")
def served():
    if not (SITE / "index.html").is_file():
        pytest.skip("no built site: `make docs` builds it (and `make test` does first)")
    if chromium_path() is None:
        pytest.skip("no Chromium (see tests/viewer/test_ui_browser.py)")
    handler = functools.partial(http.server.SimpleHTTPRequestHandler, directory=str(SITE))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    from playwright.sync_api import sync_playwright

    with sync_playwright() as playwright:
        browser = launch(playwright)
        yield browser, f"http://127.0.0.1:{server.server_address[1]}/"
        browser.close()
    server.shutdown()


@pytest.mark.parametrize("page_path, expect", [
    ("", "gsjax"),
    ("reference/api/raster/", "gsjax.raster.render.render"),
    ("tutorials/render_and_grad/", "jax.grad"),
])
def test_a_page_of_the_site_loads_cleanly(served, page_path, expect):
    browser, root = served
    page, log = open_page(browser, root + page_path, allowed=(root, "data:", "blob:"))
    try:
        page.wait_for_load_state("networkidle")
        assert expect in page.content()
        assert not log.errors and not log.exceptions and not log.outside, (log.errors, log.exceptions, log.outside)
        if page_path.startswith("tutorials/"):
            figures = page.locator("img[src^='data:image/png']")
            if (SITE / ".tutorials-not-run").exists():  # `make test`'s quick build: the code, no outputs
                assert figures.count() == 0 and "plt.show()" in page.locator("body").inner_text()
            else:
                assert figures.count() >= 2, ("no figures in the tutorial: the site was built without running the "
                                              "tutorials (GSJAX_DOCS_EXECUTE=false?); `make docs` runs them")
                assert all(figures.nth(i).evaluate("img => img.naturalWidth > 0") for i in range(figures.count()))
    finally:
        page.context.close()


def test_the_method_page_draws_its_formulas_as_mathml(served):
    """The formulas are MathML converted at build time (docs/hooks/mathml.py): no script, nothing from outside, and
    Chromium lays each one out as maths (display ``math`` / ``block math``, not an unknown inline element) with a
    size, inline and displayed; no LaTeX is left as text."""
    browser, root = served
    page, log = open_page(browser, root + "method/", allowed=(root, "data:", "blob:"))
    try:
        page.wait_for_load_state("networkidle")
        assert not log.errors and not log.exceptions and not log.outside, (log.errors, log.exceptions, log.outside)
        formulas = page.locator("article math")
        assert formulas.count() >= 1
        boxes = formulas.evaluate_all(
            "els => els.map(e => { const r = e.getBoundingClientRect();"
            " return [getComputedStyle(e).display, r.width, r.height]; })")
        drawn = [display in ("math", "block math") and width > 0 and height > 0 for display, width, height in boxes]
        assert all(drawn), [box for box, ok in zip(boxes, drawn) if not ok]
        assert {"math", "block math"} <= {display for display, _, _ in boxes}
        text = page.locator("article").inner_text()
        assert "\\(" not in text and "\\[" not in text and "$$" not in text
    finally:
        page.context.close()


def test_the_docstrings_roles_are_cross_references_not_text():
    """``:func:`x``` in a docstring renders as a link where x is on the site, else as code (docs/hooks/roles.py);
    no page shows a role as text."""
    if not (SITE / "index.html").is_file():
        pytest.skip("no built site: `make docs` builds it (and `make test` does first)")
    pages = {path: path.read_text(encoding="utf-8") for path in SITE.rglob("*.html")}
    left = {str(path.relative_to(SITE)): n for path, text in pages.items()
            if (n := len(re.findall(r":(?:func|class|mod|meth|attr|data|obj|exc):<code>", text)))}
    assert not left, left
    slam = pages[SITE / "reference" / "api" / "slam" / "index.html"]
    assert 'href="../raster_modules/#gsjax.raster.cbknn.CBKNN"><code>gsjax.raster.cbknn.CBKNN</code></a>' in slam
