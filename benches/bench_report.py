"""Benchmark ``lightemma report`` at full size: 13 models × 3,908 frames (the paper's test set).

Three figures, each against its goal (issues 24 and 26):

* ``report`` against ``report --no-pictures``, side by side (run in turn, A B A B …, ratio taken pair by
  pair): goal ≤ 2× (a placeholder camera costs nothing, each figure is drawn once, SVG only with --svg);
* the report folder's size: goal < 300 MB;
* ``index.html`` opened from file:// in headless Chromium (Debian's chromium + chromedriver through
  selenium): time from navigation to the frame data parsed (``LE.ready``), to the frame browser's first
  thumbnails, and to a frame view with its stage texts; goal < 3 s to open.

The runs are synthetic (``lightemma.evaluation.synthetic``) and made to look like the imported reference
runs a user reports on: each record carries the CAM_FRONT calibration and an image name but no image is on
disk (the grey "image not available" placeholder case that issue 26 measured), and stage texts of about
real length. Usage::

    python benches/bench_report.py                       # write runs into a temp folder, measure, delete
    python benches/bench_report.py --keep /tmp/bench-report --reps 3
    python benches/bench_report.py --keep /tmp/bench-report --open-only   # reuse runs and reports
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

MODELS = (
    "openai/gpt-4o",
    "openai/gpt-4.1",
    "openai/gpt-5.2",
    "anthropic/claude-3-7-sonnet-20250219",
    "anthropic/claude-sonnet-4-20250514",
    "gemini/gemini-2.0-flash",
    "gemini/gemini-2.5-flash",
    "gemini/gemini-2.5-pro",
    "qwen/qwen2.5-vl-7b",
    "qwen/qwen2.5-vl-72b",
    "meta/llama-3.2-11b-vision",
    "baseline:cv",
    "baseline:constant",
)
CAMERA = {  # nuScenes CAM_FRONT (scene-0061)
    "camera_intrinsic": [[1266.417, 0.0, 816.267], [0.0, 1266.417, 491.507], [0.0, 0.0, 1.0]],
    "translation": [1.70079, 0.01594, 1.51095],
    "rotation": [0.4998, -0.5031, 0.4998, -0.4971],
}


def write_runs(folder: Path, models: int, frames: int) -> Path:
    from lightemma.evaluation.synthetic import write_synthetic_run
    from lightemma.runs.store import FRAMES_FILE, update_manifest

    runs = folder / "runs"
    for i, model in enumerate(MODELS[:models]):
        run_dir = write_synthetic_run(runs, model, frames, seed=i, noise=0.3 + 0.15 * i, text_chars=900)
        lines = (run_dir / FRAMES_FILE).read_text().splitlines()
        with open(run_dir / FRAMES_FILE, "w", encoding="utf-8") as fh:
            for line in lines:
                record = json.loads(line)
                record.update(camera_params=CAMERA, image_name=f"{record['sample_token']}.jpg", image_path=None)
                fh.write(json.dumps(record) + "\n")
        update_manifest(run_dir, imported={"source_hash": f"bench-{i}", "source": "bench_report"})
    return runs


def side_by_side(runs: Path, folder: Path, reps: int) -> dict:
    """Wall seconds of `report` and `report --no-pictures`, in turn; the ratio pair by pair."""
    env = {**os.environ, "MPLBACKEND": "Agg"}
    base = [sys.executable, "-m", "lightemma", "report", str(runs), "--force"]
    full, bare, ratios = [], [], []
    for _ in range(reps):
        times = []
        for extra, out in (([], "full"), (["--no-pictures"], "bare")):
            start = time.perf_counter()
            subprocess.run(
                [*base, "--out", str(folder / out), *extra],
                check=True,
                env=env,
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
            )
            times.append(time.perf_counter() - start)
        full.append(times[0])
        bare.append(times[1])
        ratios.append(times[0] / times[1])
    median = lambda xs: sorted(xs)[len(xs) // 2]  # noqa: E731
    return {
        "report_s": median(full),
        "no_pictures_s": median(bare),
        "ratio": median(ratios),
        "ratios": [round(r, 2) for r in ratios],
    }


def folder_size(folder: Path) -> int:
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file())


def open_in_browser(index: Path) -> dict:
    """Seconds from navigation to LE.ready, to the first thumbnails, and to a frame view with its texts."""
    os.environ["SE_AVOID_STATS"] = "true"
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service
    from selenium.webdriver.support.ui import WebDriverWait

    options = webdriver.ChromeOptions()
    options.binary_location = shutil.which("chromium") or "/usr/bin/chromium"
    for arg in (
        "--headless=new",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-dev-shm-usage",
        "--window-size=1400,1000",
    ):
        options.add_argument(arg)
    driver = webdriver.Chrome(service=Service("/usr/bin/chromedriver"), options=options)
    try:
        wait = WebDriverWait(driver, 120, poll_frequency=0.02)
        driver.get(index.as_uri())
        wait.until(lambda d: d.execute_script("return window.LE && LE.ready === true"))
        ready = driver.execute_script("return LE.readyAt") / 1000
        t0 = time.perf_counter()
        driver.execute_script("location.hash = '#frames?sort=spread'")
        wait.until(
            lambda d: d.execute_script(
                "return document.querySelectorAll('#grid .card .thumb svg, #grid .card .thumb img').length > 0"
            )
        )
        grid = time.perf_counter() - t0
        t0 = time.perf_counter()
        driver.execute_script("location.hash = '#frame/' + LE.lastList.list[0]")
        wait.until(lambda d: d.execute_script("return document.querySelectorAll('#texts .model-texts').length > 0"))
        view = time.perf_counter() - t0
        errors = [e for e in driver.get_log("browser") if e["level"] == "SEVERE"]
    finally:
        driver.quit()
    return {
        "open_to_ready_s": round(ready, 3),
        "frames_grid_s": round(grid, 3),
        "frame_view_s": round(view, 3),
        "console_errors": len(errors),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--models", type=int, default=13)
    parser.add_argument("--frames", type=int, default=3908)
    parser.add_argument(
        "--reps", type=int, default=1, help="pairs of report runs (default 1: each takes minutes at full size)"
    )
    parser.add_argument("--keep", type=Path, help="work folder to keep (runs are reused when there)")
    parser.add_argument("--open-only", action="store_true", help="only open the kept report in the browser")
    args = parser.parse_args()
    folder = args.keep or Path(tempfile.mkdtemp(prefix="bench-report-"))
    folder.mkdir(parents=True, exist_ok=True)
    try:
        runs = folder / "runs"
        if not runs.is_dir():
            start = time.perf_counter()
            write_runs(folder, args.models, args.frames)
            print(f"wrote {args.models} runs × {args.frames} frames in {time.perf_counter() - start:.1f} s")
        result: dict = {"models": args.models, "frames": args.frames}
        if not args.open_only:
            result.update(side_by_side(runs, folder, args.reps))
        report = folder / "full"
        result["report_mb"] = round(folder_size(report) / 1e6, 1)
        result["no_pictures_mb"] = round(folder_size(folder / "bare") / 1e6, 1) if (folder / "bare").is_dir() else None
        result.update(open_in_browser(report / "index.html"))
        print(json.dumps(result, indent=2))
        print(
            f"goals: report ≤ 2× --no-pictures ({result.get('ratio', float('nan')):.2f}×), folder < 300 MB ({result['report_mb']} MB), "
            f"opens < 3 s ({result['open_to_ready_s']} s)"
        )
    finally:
        if args.keep is None:
            shutil.rmtree(folder, ignore_errors=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
