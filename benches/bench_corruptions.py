"""Is corruption the bottleneck of a corrupted run? Corrupting frames against encoding them for the request.

For ``--frames`` frames at 1600 × 900 (synthetic CAM_FRONT photos of ``lightemma synth``, reused in turn), and for each
corruption of :mod:`lightemma.corruptions` at ``--severity``, this times

* **corrupt**: :func:`lightemma.corruptions.corrupt_array` on the decoded RGB image (the albumentations transform,
  seeded per frame as a run seeds it), and
* **encode**: what every corrupted image then costs to be sent: the JPEG encoding at quality 95
  (:func:`lightemma.corruptions.encode_jpeg`) and its base64 for the request body,

and prints, per corruption, both CPU times (all threads of the process) and wall times, and their ratio
corrupt / encode (< 1: corrupting costs less than encoding). Decoding the source JPEG is needed by both and is
reported once. Times are totals over ``--frames`` frames; ``--frames 3908`` is the paper's set.

    python benches/bench_corruptions.py [--frames 3908] [--severity 3] [--names fog,rain] [--source camera-like]
                                        [--json out.json]
"""

from __future__ import annotations

import argparse
import base64
import io
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from PIL import Image

os.environ.setdefault("NO_ALBUMENTATIONS_UPDATE", "1")
ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "python"))

from lightemma.corruptions import NAMES, corrupt_array, corruption_seed, encode_jpeg  # noqa: E402


def photos(n_distinct: int, source: str) -> list[tuple[str, np.ndarray]]:
    """(sample token, decoded RGB (900, 1600, 3)) of ``n_distinct`` 1600 × 900 frames: ``synth`` photos (smooth,
    cheap to encode) or ``camera-like`` ones (tests/support/memframes.py: a gradient with pixel noise that compresses like a
    CAM_FRONT photo, about 160 KiB)."""
    if source == "camera-like":
        sys.path.insert(0, str(ROOT))
        from tests.support.memframes import make_frames

        frames = make_frames(Path(tempfile.mkdtemp(prefix="bench-corrupt-")), n_distinct, image_size=(1600, 900))
        return [(f.sample_token, np.asarray(Image.open(f.image_path).convert("RGB"))) for f in frames]
    import lightemma.synth
    from lightemma.nuscenes import load_frames

    root = Path(tempfile.mkdtemp(prefix="bench-corrupt-"))
    lightemma.synth.write_dataset(
        root, scenes=max(1, -(-n_distinct // 4)), keyframes=18, image_size=(1600, 900), sweeps=False
    )
    frames = list(load_frames(root, "v1.0-mini"))[:n_distinct]
    out = []
    for f in frames:
        with Image.open(f.image_path) as img:
            out.append((f.sample_token, np.asarray(img.convert("RGB"))))
    return out


def timed(fn) -> tuple[float, float]:
    cpu, wall = time.process_time(), time.perf_counter()
    fn()
    return time.process_time() - cpu, time.perf_counter() - wall


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=3908)
    ap.add_argument("--distinct", type=int, default=16, help="distinct synthetic photos, reused in turn")
    ap.add_argument("--severity", type=int, default=3)
    ap.add_argument("--names", default=",".join(NAMES))
    ap.add_argument("--source", choices=("synth", "camera-like"), default="synth")
    ap.add_argument("--json")
    args = ap.parse_args()
    images = photos(args.distinct, args.source)
    order = [images[i % len(images)] for i in range(args.frames)]
    corrupt_array(order[0][1], "brightness", 1, 0)  # albumentations imported outside the timings

    # the source decode, once: what a corrupted request adds before the transform (shared by every corruption)
    sources = [encode_jpeg(rgb) for _, rgb in images]

    def decode() -> None:
        for i in range(args.frames):
            np.asarray(Image.open(io.BytesIO(sources[i % len(sources)])).convert("RGB"))

    decode_cpu, decode_wall = timed(decode)
    rows = []
    print(
        f"{args.frames} {args.source} frames at 1600x900, severity {args.severity}; "
        f"source JPEG decode {decode_cpu:.2f} s CPU ({decode_wall:.2f} s wall)"
    )
    print(
        f"{'corruption':<15} {'corrupt CPU':>12} {'encode CPU':>11} {'ratio':>6} {'corrupt wall':>13} "
        f"{'encode wall':>12}"
    )
    for name in args.names.split(","):
        corrupted: list[np.ndarray] = []

        def corrupt() -> None:
            for token, rgb in order:
                corrupted.append(corrupt_array(rgb, name, args.severity, corruption_seed(token, name, args.severity)))

        def encode() -> None:
            for out in corrupted:
                base64.b64encode(encode_jpeg(out))

        c_cpu, c_wall = timed(corrupt)
        e_cpu, e_wall = timed(encode)
        rows.append(
            {
                "name": name,
                "corrupt_cpu_s": c_cpu,
                "encode_cpu_s": e_cpu,
                "corrupt_wall_s": c_wall,
                "encode_wall_s": e_wall,
                "ratio_cpu": c_cpu / e_cpu,
            }
        )
        print(
            f"{name:<15} {c_cpu:>12.2f} {e_cpu:>11.2f} {c_cpu / e_cpu:>6.2f} {c_wall:>13.2f} {e_wall:>12.2f}",
            flush=True,
        )
    total_c, total_e = sum(r["corrupt_cpu_s"] for r in rows), sum(r["encode_cpu_s"] for r in rows)
    print(f"{'all':<15} {total_c:>12.2f} {total_e:>11.2f} {total_c / total_e:>6.2f}")
    if args.json:
        summary = {
            "frames": args.frames,
            "source": args.source,
            "severity": args.severity,
            "rows": rows,
            "decode_cpu_s": decode_cpu,
            "decode_wall_s": decode_wall,
        }
        Path(args.json).write_text(json.dumps(summary, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
