"""What ``gsjax run --viewer`` costs a run: the same run without the viewer, with it and no browser connected,
and with a headless Chromium connected throughout on the same cores as the SLAM, showing the map as points (the
live viewer's default while the run goes on) or, switched in the page, as splats. viser's splats keep a depth sort
running in the browser (more than one core of this machine's two while the page is open), so a browser on the
SLAM's own few cores is the worst case; on another machine it costs the run nothing.

    python experiments/bench_viewer.py --dataset synthetic --max-frames 30
    python experiments/bench_viewer.py --dataset 7scenes --path ../shared/data/7scenes_redkitchen --max-frames 40

One warm-up run fills the compilation cache; then the cases run ``--repeats`` times each, interleaved. A run's
time is its SLAM time (``stage_timings_s.slam_s``: the scan chunks, compilation included, which every case loads
from the cache) plus the viewer's synchronous updates between chunks (``observe_s``). Prints a table and writes
``experiments/results/bench_viewer_<dataset>.json``.
"""

from __future__ import annotations

import argparse
import json
import signal
import statistics
import sys
import tempfile
from pathlib import Path

from gsjax.eval.run_metrics import read_run_metrics
from gsjax.viewer.browser import Process, launch, open_page

ROOT = Path(__file__).resolve().parents[1]

CASES = ("no viewer", "viewer, no browser", "viewer, browser (map as points)", "viewer, browser, map as splats")


def run_once(case: str, sequence_args: list[str], out: Path, browser) -> dict:
    args = ["run", "--out", str(out), "--overwrite", "--no-progress", *sequence_args]
    if case == "no viewer":
        process = Process(args)
        assert process.finish() == 0, "\n".join(process.lines)
    else:
        process = Process([*args, "--viewer", "--viewer-port", "0"])
        url = process.wait_for(r"viewer: (http://\S+) \(updated", 600).group(1)
        page = None
        if case.startswith("viewer, browser"):
            page, _ = open_page(browser, url, allowed=(url, "data:", "blob:"))
            if case.endswith("splats"):  # the viewer's "map as" choice, made in the page as a user would
                page.locator("input.mantine-Select-input:visible").first.click()
                page.get_by_role("option", name="splats").click()
        process.wait_for(r"shows the finished run", 3600)
        if page is not None:
            page.context.close()
        assert process.stop(signal.SIGTERM) == 0, "\n".join(process.lines)
    metrics = read_run_metrics(out / "metrics.json")
    timings, frames = metrics.stage_timings_s, metrics.frames
    seconds = timings["slam_s"] + timings.get("observe_s", 0.0)
    return dict(slam_s=timings["slam_s"], observe_s=timings.get("observe_s", 0.0), seconds=seconds,
                seconds_per_frame=seconds / frames)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", default="synthetic")
    parser.add_argument("--path", default=None)
    parser.add_argument("--max-frames", type=int, default=30)
    parser.add_argument("--cbknn", default="off")
    parser.add_argument("--repeats", type=int, default=2)
    args = parser.parse_args()
    sequence_args = ["--dataset", args.dataset, "--max-frames", str(args.max_frames), "--cbknn", args.cbknn]
    if args.path:
        sequence_args += ["--path", args.path]
    from playwright.sync_api import sync_playwright

    results: dict[str, list[dict]] = {case: [] for case in CASES}
    with tempfile.TemporaryDirectory() as work, sync_playwright() as playwright:
        browser = launch(playwright)
        run_once("no viewer", sequence_args, Path(work) / "warmup", browser)
        for repeat in range(args.repeats):
            for case in CASES:
                result = run_once(case, sequence_args, Path(work) / "run", browser)
                results[case].append(result)
                print(f"{case:28s} run {repeat + 1}: SLAM {result['slam_s']:.1f} s + viewer updates "
                      f"{result['observe_s']:.2f} s", flush=True)
        browser.close()
    base = statistics.median(r["seconds"] for r in results["no viewer"])
    summary = {}
    print(f"\n{'case':28s} {'s/frame':>8s} {'updates (s)':>12s} {'slowdown':>9s}")
    for case in CASES:
        seconds = statistics.median(r["seconds"] for r in results[case])
        summary[case] = dict(median_seconds=seconds, median_seconds_per_frame=seconds / args.max_frames,
                             median_observe_s=statistics.median(r["observe_s"] for r in results[case]),
                             slowdown_percent=100 * (seconds / base - 1), runs=results[case])
        print(f"{case:28s} {seconds / args.max_frames:8.3f} {summary[case]['median_observe_s']:12.2f} "
              f"{summary[case]['slowdown_percent']:+8.1f}%")
    out = ROOT / "experiments" / "results" / f"bench_viewer_{args.dataset}.json"
    out.write_text(json.dumps(dict(command=" ".join(["python", "experiments/bench_viewer.py", *sys.argv[1:]]),
                                   frames=args.max_frames, cases=summary), indent=2) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
