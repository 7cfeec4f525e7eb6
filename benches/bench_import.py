"""Benchmark ``lightemma import`` on a paper-sized set of reference result folders: time and peak memory.

Writes 13 model folders in the reference scripts' format (``<model>/output/<scene>.json``,
150 scenes, 3,908 frames each: the paper's v1.0-test set; texts of realistic length
split into lines of at most 80 characters, ``json.dump(indent=4)`` as the scripts
wrote them; each stage's prompt a fixed text with the frame's scene description,
history and intent filled in, as the reference chain builds them; most answers
strict, a few lists of lists, prose, or unreadable), then,
each in a fresh subprocess so that peak RSS is clean:

* ``import``   — ``lightemma import`` of all 13 folders (parse, check, write the runs) with the
  default worker processes (one per folder, at most 4 and the CPUs);
* ``import-serial`` — the same in one process (``--jobs 1``);
* ``again``    — the same import again (finds every run by its source hash, writes nothing);
* ``evaluate`` — ``evaluate_runs`` over the 13 imported runs (paper rules, all conventions);

and then, side by side (``--repeat`` times in turn, medians), ``import-serial`` against its anchor:

* ``naive``    — a naive converter, the least any converter does: each scene file ``json.loads``-ed, each
  frame written back as one ``json.dumps`` line (no checks, no parsing, no sidecar), one process.

Usage::

    python benches/bench_import.py                          # 13 models x 3,908 frames
    python benches/bench_import.py --models 2 --keep /tmp/b  # smaller, keep the files (reused next time)
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

import numpy as np

MODELS = (
    "gpt-4o",
    "gpt-5",
    "gpt-5.2",
    "claude-3.7-sonnet",
    "claude-4.0-sonnet",
    "claude-4.6-sonnet",
    "gemini-2.0-flash",
    "gemini-2.5-flash",
    "gemini-3.0-flash",
    "qwen-2.5-7b",
    "qwen-3.0-8b",
    "llama-3.2-11b",
    "llama-3.2-90b",
)
SCENES, FRAMES = 150, 3908
WORDS = (
    "the road ahead vehicle lane marking pedestrian crossing traffic light green red parked truck cyclist "
    "intersection sidewalk moving slowly ahead of the ego car on the left right side of the street with a bus"
).split()

CHILD = r"""
import json, resource, sys, time
import numpy, lightemma
mode, src, out = sys.argv[1], sys.argv[2], sys.argv[3]
start = time.perf_counter()
if mode.startswith("import") or mode == "again":
    from lightemma.runs.importer import default_jobs, import_reference
    from lightemma.runs.reference import find_model_folders
    jobs = 1 if mode == "import-serial" else default_jobs(len(find_model_folders(src)))
    results = import_reference([src], out + ("-serial" if mode == "import-serial" else ""), jobs=jobs)
    result = {"outcomes": sorted({r.outcome for r in results}), "jobs": jobs, "frames": sum(r.frames for r in results)}
elif mode == "evaluate":
    from lightemma.evaluation import evaluate_runs
    ev = evaluate_runs([out], convention="all")
    result = sum(m.frames_in_run for m in ev.models)
elif mode == "naive":
    from pathlib import Path
    result = 0
    for model in sorted(p for p in Path(src).iterdir() if (p / "output").is_dir()):
        target = Path(out + "-naive") / model.name
        target.mkdir(parents=True, exist_ok=True)
        with open(target / "frames.jsonl", "w") as fh:
            for path in sorted((model / "output").glob("*.json")):
                doc = json.loads(path.read_bytes())
                for frame in doc["frames"]:
                    inference = {k: " ".join(v) if isinstance(v, list) else v for k, v in frame["inference"].items()}
                    fh.write(json.dumps({"frame_id": doc["scene_info"]["name"] + "/" + frame["sample_token"], **frame,
                                         "inference": inference}) + "\n")
                    result += 1
else:
    result = None
seconds = time.perf_counter() - start
me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
print(json.dumps({"seconds": seconds, "cpu_seconds": me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime,
                  "maxrss_mb": me.ru_maxrss / 1024, "children_maxrss_mb": kids.ru_maxrss / 1024, "result": result}))
"""


def measure(mode: str, src: Path, out: Path) -> dict:
    done = subprocess.run(
        [sys.executable, "-c", CHILD, mode, str(src), str(out)], check=True, capture_output=True, text=True
    )
    return json.loads(done.stdout)


def split_lines(text: str) -> list[str]:
    from lightemma.runs.reference import split_lines as split

    return split(text)


def sentence(rng: np.random.Generator, words: int) -> str:
    return " ".join(rng.choice(WORDS, words)) + "."


def answer(rng: np.random.Generator, fe_rate: float) -> str:
    pairs = [(round(float(rng.uniform(0, 14)), 2), round(float(rng.normal(0, 0.01)), 4)) for _ in range(6)]
    u = rng.random()
    if u >= fe_rate:
        return "[" + ", ".join(f"({v}, {c})" for v, c in pairs) + "]"
    if u < fe_rate * 0.4:
        return "[" + ", ".join(f"[{v}, {c}]" for v, c in pairs) + "]"
    if u < fe_rate * 0.8:
        return "Here are the actions: " + ", ".join(f"({v}, {c})" for v, c in pairs)
    return "I cannot tell from this image."


# The reference scripts' chain (the paper's section "VLM Prompting"): one fixed prompt per stage, the scene
# description fed into stages 2 and 3, the driving intent into stage 3, the history of (speed, curvature)
# into both. Written here in our own words at the reference prompts' lengths (~380, ~630 and ~690 characters
# of fixed text); what varies from frame to frame is what the reference filled in.
SCENE_PROMPT = (
    "You are an autonomous driving labeller. You have access to the front-view camera image of a car. "
    "Imagine you are driving the car. Describe the driving scene according to traffic lights, the movements "
    "of other cars or pedestrians and the lane markings. Be concise and factual, mention every object that "
    "matters for driving and where it is, and do not speculate about anything the image does not show."
)
INTENT_PROMPT = (
    "You are an autonomous driving labeller. You have access to the front-view camera image of a car taken "
    "at a 2 Hz frequency. Imagine you are driving the car. The scene is described as follows: {scene} The "
    "ego vehicle's historical speeds (m/s) over the last 3 seconds, oldest first, were {speeds} and its "
    "curvatures (1/m) were {curvatures}; a positive curvature is a left turn, a negative one a right turn. "
    "Describe what the ego vehicle has been doing: is it accelerating or decelerating, and by about how "
    "much, is it turning or following its lane? Then, from the scene and this history, predict the driving "
    "intent for the next 3 seconds in one or two sentences. Do not output numbers for the future; a "
    "high-level intent only, such as keeping the lane at a steady speed or slowing for the vehicle ahead."
)
ACTIONS_PROMPT = (
    "You are an autonomous driving labeller. You have access to the front-view camera image of a car taken "
    "at a 2 Hz frequency. Imagine you are driving the car. The scene is described as follows: {scene} The "
    "ego vehicle's historical speeds (m/s) over the last 3 seconds, oldest first, were {speeds} and its "
    "curvatures (1/m) were {curvatures}. The high-level driving intent for the next 3 seconds is: "
    "{intent} Predict the speed and curvature of the ego vehicle for each of the next 6 time steps at "
    "0.5 s intervals (3 seconds in all), physically feasible for a passenger car and consistent with the "
    "scene and the intent. Output exactly this format and nothing else, no explanation and no code "
    "fence: [(v1, c1), (v2, c2), (v3, c3), (v4, c4), (v5, c5), (v6, c6)]"
)


def frame(rng: np.random.Generator, scene: str, index: int, fe_rate: float) -> dict:
    speeds = [round(float(v), 3) for v in rng.uniform(0, 12, 6)]
    curvatures = [round(float(c), 3) for c in rng.normal(0, 0.02, 6)]
    description = " ".join(sentence(rng, 18) for _ in range(7))
    intent = " ".join(sentence(rng, 16) for _ in range(5))
    scene_prompt = SCENE_PROMPT
    intent_prompt = INTENT_PROMPT.format(scene=description, speeds=speeds, curvatures=curvatures)
    actions_prompt = ACTIONS_PROMPT.format(scene=description, speeds=speeds, curvatures=curvatures, intent=intent)
    gt = np.cumsum(rng.uniform(0, 6, (6, 2)), axis=0).round(6).tolist()
    return {
        "frame_index": index,
        "sample_token": f"{rng.integers(0, 2**63):016x}{rng.integers(0, 2**63):016x}",
        "image_name": f"n008-2018-08-01-15-16-36-0400__CAM_FRONT__{1533150000012404 + index * 500000}.jpg",
        "timestamp": 1533150000012404 + index * 500000,
        "camera_params": {
            "rotation": [0.4998, -0.503, 0.4997, -0.4973],
            "translation": [1.7, 0.016, 1.511],
            "camera_intrinsic": [[1266.4, 0.0, 816.3], [0.0, 1266.4, 491.5], [0.0, 0.0, 1.0]],
        },
        "ego_info": {
            "position": [float(rng.uniform(0, 2000)), float(rng.uniform(0, 2000))],
            "heading": float(rng.uniform(-3, 3)),
            "obs_positions": (-np.cumsum(rng.uniform(0, 6, (8, 2)), axis=0)[::-1]).round(6).tolist(),
            "obs_actions": [[s, c] for s, c in zip(speeds, curvatures)],
            "gt_positions": gt,
            "gt_actions": rng.uniform(0, 10, (6, 2)).round(3).tolist(),
        },
        "inference": {
            "scene_prompt": split_lines(scene_prompt),
            "scene_description": split_lines(description),
            "intent_prompt": split_lines(intent_prompt),
            "driving_intent": split_lines(intent),
            "waypoint_prompt": split_lines(actions_prompt),
            "pred_actions_str": answer(rng, fe_rate),
        },
        "token_usage": {
            k: {"input": int(rng.integers(800, 2500)), "output": int(rng.integers(30, 250))}
            for k in ("scene_prompt", "intent_prompt", "waypoint_prompt")
        },
        "time_usage": {
            k: round(float(rng.uniform(0.5, 8)), 3) for k in ("scene_prompt", "intent_prompt", "waypoint_prompt")
        },
    }


def write_results(root: Path, models: int) -> tuple[int, float]:
    """The model folders; returns (frames per model, MB written)."""
    sizes = [FRAMES // SCENES + (1 if s < FRAMES % SCENES else 0) for s in range(SCENES)]
    total = 0
    for m, model in enumerate(MODELS[:models]):
        rng = np.random.default_rng(m)
        out = root / model / "output"
        out.mkdir(parents=True)
        fe_rate = 0.08 if m == 0 else 0.01
        for s, n in enumerate(sizes):
            name = f"scene-{s + 1:04d}"
            doc = {
                "scene_info": {
                    "name": name,
                    "description": "generated",
                    "first_sample_token": "",
                    "last_sample_token": "",
                },
                "frames": [frame(rng, name, i, fe_rate) for i in range(n)],
                "metadata": {"model": model, "timestamp": "20250101-120000", "total_frames": n},
            }
            text = json.dumps(doc, indent=4)
            (out / f"{name}.json").write_text(text)
            total += len(text)
    return sum(sizes), total / 1e6


def side_by_side(root: Path, repeat: int) -> None:
    """``import-serial`` and the naive converter in turn, ``repeat`` times each: medians and their ratio."""
    import statistics

    runs: dict[str, list[dict]] = {"import-serial": [], "naive": []}
    for _ in range(repeat):
        for mode in runs:
            for old in root.glob("runs*"):
                shutil.rmtree(old)
            runs[mode].append(measure(mode, root / "results", root / "runs"))
    med = {
        mode: {k: statistics.median(m[k] for m in ms) for k in ("seconds", "cpu_seconds")} for mode, ms in runs.items()
    }
    naive_mb = sum(f.stat().st_size for f in (root / "runs-naive").rglob("*") if f.is_file()) / 1e6
    print(f"\nside by side, medians of {repeat} in turn (one process each):")
    for mode, m in med.items():
        print(f"{mode:>13}: {m['seconds']:6.1f} s wall, {m['cpu_seconds']:6.1f} s CPU")
    a, b = med["import-serial"], med["naive"]
    print(
        f"import / naive converter: {a['cpu_seconds'] / b['cpu_seconds']:.2f}x CPU, {a['seconds'] / b['seconds']:.2f}x wall "
        f"(the naive converter writes {naive_mb:.0f} MB)"
    )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", type=int, default=len(MODELS), choices=range(1, len(MODELS) + 1), metavar="N")
    parser.add_argument(
        "--repeat", type=int, default=3, help="side-by-side runs of import-serial and the naive converter"
    )
    parser.add_argument("--keep", type=Path, help="write here and keep (default: a temporary folder)")
    args = parser.parse_args()
    root = args.keep or Path(tempfile.mkdtemp(prefix="bench-import-"))
    try:
        for old in root.glob("runs*"):
            shutil.rmtree(old)
        if (root / "results").is_dir():  # --keep of an earlier run: reuse its folders
            megabytes = sum(f.stat().st_size for f in (root / "results").rglob("*.json")) / 1e6
            print(f"reusing {root / 'results'} ({megabytes:.0f} MB)")
        else:
            start = time.perf_counter()
            frames, megabytes = write_results(root / "results", args.models)
            print(
                f"wrote {args.models} model folder(s) x {frames} frames ({SCENES} scene files each), {megabytes:.0f} MB, "
                f"in {time.perf_counter() - start:.0f} s"
            )
        base = measure("baseline", root, root)["maxrss_mb"]
        print(
            f"baseline process (python + numpy + lightemma): {base:.0f} MB RSS; load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs"
        )
        for mode in ("import", "import-serial", "again", "evaluate"):
            m = measure(mode, root / "results", root / "runs")
            jobs = m["result"].get("jobs", 1) if isinstance(m["result"], dict) else 1
            workers = f", largest worker {m['children_maxrss_mb']:.0f} MB x {jobs} jobs" if jobs > 1 else ""
            print(
                f"{mode:>13}: {m['seconds']:6.1f} s wall, {m['cpu_seconds']:6.1f} s CPU   peak RSS {m['maxrss_mb']:5.0f} MB{workers}   {m['result']}",
                flush=True,
            )
        runs = sum(f.stat().st_size for f in (root / "runs").rglob("*") if f.is_file()) / 1e6
        print(f"runs written: {runs:.0f} MB")
        side_by_side(root, args.repeat)
    finally:
        if args.keep is None:
            shutil.rmtree(root, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
