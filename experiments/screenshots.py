"""The README's screenshots of the report and the viewer, taken in headless Chromium as the browser tests do.

    python experiments/screenshots.py                       # runs the 7-Scenes sample (40 frames, CB-KNN paper) first
    python experiments/screenshots.py --run outputs/kitchen  # or shows an existing run

Writes ``docs/figures/report.png`` (the top of report.html), ``report_renders.png`` (its render-vs-input
section), ``report_cbknn.png`` (its CB-KNN diagnostics, when the run had them) and ``viewer.png`` (``gsjax view``).
"""

from __future__ import annotations

import argparse
import signal
import sys
from pathlib import Path

from gsjax.viewer.browser import Process, decode, drawn_fraction, launch, open_page, wait_until

ROOT = Path(__file__).resolve().parents[1]

FIGURES = ROOT / "docs" / "figures"
WIDTH, HEIGHT = 1280, 860


def make_run(out: Path) -> None:
    kitchen = ROOT.parent / "shared" / "data" / "7scenes_redkitchen"
    process = Process(["run", "--dataset", "7scenes", "--path", str(kitchen), "--max-frames", "40", "--cbknn",
                       "paper", "--out", str(out), "--no-progress"])
    code = process.finish()
    print("\n".join(process.lines))
    if code != 0:
        sys.exit(f"gsjax run failed with exit status {code}")


def report_shots(browser, run: Path) -> None:
    url = (run / "report.html").resolve().as_uri()
    page, log = open_page(browser, url, allowed=(url, "data:"), width=WIDTH, height=HEIGHT)
    assert not log.problems(), log.problems()
    (FIGURES / "report.png").write_bytes(page.screenshot())
    for section, name in (("renders", "report_renders.png"), ("cbknn", "report_cbknn.png")):
        element = page.locator(f"section#{section}")
        if element.count():
            (FIGURES / name).write_bytes(element.screenshot())
    page.context.close()


def viewer_shot(browser, run: Path) -> None:
    process = Process(["view", str(run), "--port", "0"])
    try:
        url = process.wait_for(r"viewer: (http://\S+) shows", 120).group(1)
        page, log = open_page(browser, url, allowed=(url, "data:", "blob:"), width=WIDTH, height=HEIGHT)
        wait_until(lambda: drawn_fraction(decode(page.screenshot())) > 0.2, 120, "the map")
        wait_until(lambda: page.get_by_text("render, keyframe").count(), 120, "the keyframe's render")
        notice = page.get_by_text("Software WebGL rendering detected")  # headless Chromium has no GPU
        if notice.count():
            page.locator(".mantine-Notification-closeButton").first.click()
        page.wait_for_timeout(1500)
        assert not log.problems(), log.problems()
        (FIGURES / "viewer.png").write_bytes(page.screenshot())
        page.context.close()
        process.stop(signal.SIGINT)
    finally:
        process.kill()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", type=Path, default=ROOT / "outputs" / "screenshots_kitchen_paper")
    args = parser.parse_args()
    if not (args.run / "metrics.json").is_file():
        make_run(args.run)
    from playwright.sync_api import sync_playwright

    FIGURES.mkdir(parents=True, exist_ok=True)
    with sync_playwright() as playwright:
        browser = launch(playwright)
        report_shots(browser, args.run)
        viewer_shot(browser, args.run)
        browser.close()
    print(f"wrote {', '.join(sorted(p.name for p in FIGURES.glob('report*.png')))}, viewer.png in {FIGURES}")


if __name__ == "__main__":
    main()
