"""Helpers shared by test_frames.py and test_synth.py (imported explicitly, not a conftest).

``reference_frames`` is an independent, scalar, pure-Python reading of the raw
nuScenes JSON tables following docs/definitions.md#frames-and-windows word by word; the loader's vectorised
devkit-based output is compared against it.
"""

from __future__ import annotations

import json
import math
import os
import shutil
from pathlib import Path

import pytest

from lightemma.synth import write_dataset

SMALL = dict(scenes=8, seed=3, keyframes=20, image_size=(320, 180))


def make_small_dataset(root: Path, **overrides) -> Path:
    """An 8-scene (every kind once), 20-keyframe, 320x180 synthetic dataset."""
    kwargs = {**SMALL, **overrides}
    return write_dataset(root, **kwargs)


_BUILT: dict[str, Path] = {}


@pytest.fixture(scope="session")
def small_root(tmp_path_factory) -> Path:
    """Built once per test session, even when several modules import this fixture."""
    if "small" not in _BUILT:
        _BUILT["small"] = make_small_dataset(tmp_path_factory.mktemp("synth-small"))
    return _BUILT["small"]


@pytest.fixture
def small_copy(small_root, tmp_path) -> Path:
    """A private copy of the small dataset that a test may damage."""
    dst = tmp_path / "copy"
    shutil.copytree(small_root, dst)
    return dst


def read_table(root: Path, version: str, name: str) -> list[dict]:
    with open(os.path.join(root, version, f"{name}.json"), encoding="utf-8") as f:
        return json.load(f)


def _yaw(q):
    w, x, y, z = q
    return math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


def _menger(a, b, c):
    area2 = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
    la = math.dist(a, b)
    lb = math.dist(b, c)
    lc = math.dist(a, c)
    prod = la * lb * lc
    return 0.0 if prod == 0 else 4 * (area2 / 2) / prod


def reference_frames(root: Path, version: str, window: str = "reference") -> dict[str, dict]:
    """Frames computed independently from the raw JSON tables (all scenes), keyed by frame id."""
    scenes = read_table(root, version, "scene")
    samples = {s["token"]: s for s in read_table(root, version, "sample")}
    sds = read_table(root, version, "sample_data")
    poses = {p["token"]: p for p in read_table(root, version, "ego_pose")}
    sensors = {s["token"]: s for s in read_table(root, version, "sensor")}
    cals = {c["token"]: c for c in read_table(root, version, "calibrated_sensor")}
    cam_sd = {}
    for sd in sds:
        if (
            sd["is_key_frame"]
            and sensors[cals[sd["calibrated_sensor_token"]]["sensor_token"]]["channel"] == "CAM_FRONT"
        ):
            cam_sd[sd["sample_token"]] = sd
    out = {}
    for scene in sorted(scenes, key=lambda s: s["name"]):
        chain = []
        tok = scene["first_sample_token"]
        while tok:
            chain.append(tok)
            tok = samples[tok]["next"]
        n = len(chain)
        pts, yaws, ts = [], [], []
        for st in chain:
            pose = poses[cam_sd[st]["ego_pose_token"]]
            pts.append((pose["translation"][0], pose["translation"][1]))
            yaws.append(_yaw(pose["rotation"]))
            ts.append(pose["timestamp"])
        last = n - 8 if window == "reference" else n - 7
        for c in range(7, last + 1):
            cx, cy = pts[c]
            cos, sin = math.cos(yaws[c]), math.sin(yaws[c])

            def ego(p, cx=cx, cy=cy, cos=cos, sin=sin):
                dx, dy = p[0] - cx, p[1] - cy
                return (cos * dx + sin * dy, -sin * dx + cos * dy)

            local = {k: ego(pts[k]) for k in range(c - 7, c + 7)}
            hist = []
            for k in range(1, 7):
                a, b = c - 7 + k, c - 6 + k
                v = math.dist(local[a], local[b]) / ((ts[b] - ts[a]) * 1e-6)
                kap = _menger(local[c - 8 + k], local[c - 7 + k], local[c - 6 + k])
                v = 0.0 if v < 0.2 else v
                kap = 0.0 if abs(kap) > 0.2 else kap
                hist.append((round(v, 3) + 0.0, round(kap, 3) + 0.0))
            gt_actions = []
            for k in range(1, 7):
                a, b = c + k - 1, c + k
                v = math.dist(local[a], local[b]) / ((ts[b] - ts[a]) * 1e-6)
                gt_actions.append((v, _menger(local[a - 1], local[a], local[b])))
            fid = f"{scene['name']}/{chain[c]}"
            out[fid] = {
                "scene": scene["name"],
                "c": c,
                "n": n,
                "timestamp": ts[c],
                "history_positions": [local[k] for k in range(c - 7, c + 1)],
                "history_actions": hist,
                "gt_positions": [local[k] for k in range(c + 1, c + 7)],
                "gt_actions": gt_actions,
                "image": os.path.join(str(root), cam_sd[chain[c]]["filename"]),
            }
    return out
