"""The report and the viewer in a real browser (headless Chromium, ``tests/browser.py``).

One tiny CB-KNN paper run with ``gsjax run --viewer`` is watched live: the browser connects before the first chunk
is done and waits for the map to appear, then for the finished run, and SIGTERM stops the process cleanly. Its
``report.html`` then opens from disk with every image and no request, and ``gsjax view`` serves the finished run
(splats, keyframe images, the frame slider) until SIGINT. Every page must load without console errors or uncaught
exceptions; the canvas must not be blank.

(The file's name sorts it after the SLAM tests, whose compiled programs the subprocesses then find in the
persistent compilation cache.)
"""

from __future__ import annotations

import os
import signal
from pathlib import Path

import pytest

from gsjax.viewer.browser import Process, chromium_path, decode, drawn_fraction, launch, open_page, wait_until
from tests.support.tiny_slam import FRAMES, TINY_RUN

VIEWPORT = (1280, 860)
PANEL_PX = 380  # the viser GUI panel on the right; the scene is measured left of it
STARTUP_S = 240  # a cold start compiles the SLAM programs (a minute or more on 2 cores)


@pytest.fixture(scope="module")
def browser():
    if chromium_path() is None:
        message = ("no Chromium found (chromium, chromium-browser or $GSJAX_CHROMIUM): `make test` installs Debian's "
                   "chromium package (apt-get install chromium, as root); set GSJAX_SKIP_BROWSER_TESTS=1 to skip "
                   "the browser tests")
        if os.environ.get("GSJAX_SKIP_BROWSER_TESTS") == "1":
            pytest.skip(message)
        pytest.fail(message, pytrace=False)
    from playwright.sync_api import sync_playwright

    with sync_playwright() as playwright:
        instance = launch(playwright)
        yield instance
        instance.close()


@pytest.fixture(scope="module")
def live_run(tmp_path_factory):
    """``gsjax run --viewer`` on the tiny synthetic room with CB-KNN paper (returned while it runs)."""
    out = tmp_path_factory.mktemp("browser") / "run"
    process = Process(["run", "--out", str(out), *TINY_RUN, "--cbknn", "paper", "--viewer", "--viewer-port", "0"])
    url = process.wait_for(r"viewer: (http://\S+) \(updated", STARTUP_S).group(1)
    yield process, url, out
    process.kill()


def finished(live_run) -> Path:
    process, _, out = live_run
    process.wait_for(r"shows the finished run", STARTUP_S)
    return out


def scene_drawn(page) -> float:
    """How much of the 3D view (left of the GUI panel, below viser's software-rendering notice) is drawn."""
    width, height = VIEWPORT
    shot = decode(page.screenshot(clip=dict(x=330, y=160, width=width - PANEL_PX - 330, height=height - 240)))
    return drawn_fraction(shot)


def assert_clean(log):
    assert log.problems() == [], "\n".join(log.problems() + ["page messages:"] + log.messages)


def test_run_viewer_shows_the_map_live_and_stops_on_sigterm(browser, live_run, tmp_path):
    process, url, _ = live_run
    page, log = open_page(browser, url, allowed=(url, "data:", "blob:"), width=VIEWPORT[0], height=VIEWPORT[1])
    try:
        # The map appears when the first chunk is done, as points while the run goes on, then as splats.
        map_as = page.locator("input.mantine-Select-input:visible").first
        wait_until(lambda: scene_drawn(page) > 0.2, STARTUP_S, "the live map in the canvas")
        shown_as = map_as.input_value()
        if not process.seen(r"shows the finished run"):
            assert shown_as == "points"
        process.wait_for(r"shows the finished run", STARTUP_S)
        wait_until(lambda: map_as.input_value() == "splats", 30, "the finished map as splats")
        last = FRAMES - 1
        wait_until(lambda: page.get_by_text(f"frame {last}; keyframe 4").count(), 60, "the last frame selected")
        wait_until(lambda: page.get_by_text("render, keyframe 4").count(), 60, "the keyframe's render")
        (tmp_path / "live.png").write_bytes(page.screenshot())
        assert_clean(log)
    finally:
        page.context.close()
    assert process.stop(signal.SIGTERM) == 0
    assert "viewer stopped (SIGTERM)" in process.lines


def test_report_opens_with_every_image_and_no_request(browser, live_run, tmp_path):
    report = finished(live_run) / "report.html"
    url = report.resolve().as_uri()
    page, log = open_page(browser, url, allowed=(url, "data:"), width=VIEWPORT[0], height=VIEWPORT[1])
    try:
        images = page.evaluate("() => Array.from(document.images).map(i => [i.complete, i.naturalWidth])")
        assert len(images) == 9 and all(complete and width > 0 for complete, width in images), images
        for section in ("Metrics", "Trajectory against ground truth", "Renders against inputs", "CB-KNN diagnostics"):
            assert page.get_by_role("heading", name=section).is_visible(), section
        shot = page.screenshot(full_page=True)
        (tmp_path / "report.png").write_bytes(shot)
        assert drawn_fraction(decode(shot)) > 0.2
        assert_clean(log)
    finally:
        page.context.close()


def test_view_serves_a_finished_run_with_a_frame_slider_and_stops_on_sigint(browser, live_run, tmp_path):
    out = finished(live_run)
    process = Process(["view", str(out), "--port", "0"])
    try:
        url = process.wait_for(r"viewer: (http://\S+) shows", 120).group(1)
        page, log = open_page(browser, url, allowed=(url, "data:", "blob:"), width=VIEWPORT[0], height=VIEWPORT[1])
        try:
            wait_until(lambda: scene_drawn(page) > 0.2, 120, "the map in the canvas")
            wait_until(lambda: page.get_by_text("render, keyframe 4").count(), 60, "the last keyframe's render")
            assert page.get_by_text("input, keyframe 4").count()
            images = page.evaluate("() => Array.from(document.images).map(i => i.naturalWidth)")
            assert len(images) >= 2 and all(width > 0 for width in images), images
            # The frame slider, moved with the keyboard from the last frame to frame 2, selects keyframe 0: its
            # stored input and its render are shown.
            slider = page.get_by_role("slider").first
            assert slider.get_attribute("aria-valuemax") == str(FRAMES - 1)
            slider.focus()
            for _ in range(FRAMES - 1 - 2):
                slider.press("ArrowLeft")
            wait_until(lambda: page.get_by_text("frame 2; keyframe 0").count(), 30, "frame 2 selected")
            wait_until(lambda: page.get_by_text("render, keyframe 0").count(), 60, "keyframe 0's render")
            assert page.get_by_text("input, keyframe 0").count()
            (tmp_path / "view.png").write_bytes(page.screenshot())
            assert_clean(log)
        finally:
            page.context.close()
        assert process.stop(signal.SIGINT) == 0
        assert "viewer stopped (SIGINT)" in process.lines
    finally:
        process.kill()
