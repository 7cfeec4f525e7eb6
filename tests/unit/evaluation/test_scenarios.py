"""Scenario tags from ground truth and history; per-tag metrics; history bias; disagreement."""

from __future__ import annotations

import numpy as np
import pytest

import lightemma
from lightemma.evaluation import load_run
from lightemma.evaluation.scenarios import (
    TAGS,
    disagreements,
    history_bias,
    mean_curvature,
    per_tag_metrics,
    tag_frames,
    worst_frame_per_tag,
)
from lightemma.evaluation.synthetic import make_record
from lightemma.runs.store import RunWriter, create_run_dir


def drive(speeds, curvature=0.0):
    """GT positions of six (speed, curvature) actions (midpoint: exact on arcs)."""
    actions = np.stack([np.broadcast_to(speeds, 6), np.full(6, curvature)], axis=1).astype(float)
    return lightemma.integrate(actions, method="midpoint")


def history(speed, curvatures=(0.0,) * 6):
    return np.stack([np.full(6, float(speed)), np.asarray(curvatures, dtype=float)], axis=1)


CASES = {
    "stopped": (drive(0.0), history(0.0)),
    "starting": (drive(np.linspace(0.5, 3.0, 6)), history(0.0)),
    "braking": (drive(np.linspace(9.0, 4.0, 6)), history(10.0)),
    "accelerating": (drive(np.linspace(6.0, 9.0, 6)), history(5.0)),
    "turning_left": (drive(6.0, 0.08), history(6.0)),
    "turning_right": (drive(6.0, -0.08), history(6.0)),
    "straight_after_right_turn": (drive(8.0), history(8.0, (0, -0.1, -0.1, -0.08, -0.05, -0.01))),
    "straight_after_left_turn": (drive(8.0), history(8.0, (0, 0.1, 0.1, 0.08, 0.05, 0.01))),
    "cruising": (drive(8.0), history(8.0)),
}


def test_each_case_gets_its_tag():
    names = list(CASES)
    gt = np.stack([CASES[n][0] for n in names])
    hist = np.stack([CASES[n][1] for n in names])
    tags = tag_frames(gt, hist)
    assert list(tags) == list(TAGS)
    for i, name in enumerate(names):
        assert tags[name][i], name
        others = {t for t in TAGS if tags[t][i]} - {name}
        assert not others & {"stopped", "cruising", "turning_left", "turning_right"}, (name, others)
    assert tags["cruising"].sum() == 1  # only the plain straight frame


def test_mean_curvature_of_an_arc():
    assert mean_curvature(drive(8.0, 0.02)[None])[0] == pytest.approx(0.02, rel=1e-3)  # chords of the arc
    assert mean_curvature(drive(0.0)[None])[0] == 0.0  # stopped: degenerate triangles


def write_run(tmp_path, model, frames):
    """frames: list of (frame_id, gt, pred, history[, scene name])."""
    run_dir = create_run_dir(tmp_path, model, {"model": model, "finished_at": "t"})
    with RunWriter(run_dir) as w:
        for fid, gt, pred, hist, *scene in frames:
            w.append(make_record(fid, gt, pred, history_actions=hist, scene_name=scene[0] if scene else "scene-0001"))
    return load_run(run_dir, details=True)


def test_per_tag_metrics_match_numpy(tmp_path):
    rng = np.random.default_rng(0)
    frames = []
    for rep in range(3):
        for name, (gt, hist) in CASES.items():
            frames.append((f"{name}/{rep}", gt, gt + rng.normal(0, 0.5, (6, 2)), hist))
    run = write_run(tmp_path, "m", frames)
    rows = {r["tag"]: r for r in per_tag_metrics([run])}
    assert list(rows) == ["all", *TAGS]
    for tag in ("all", "braking", "turning_left", "cruising"):
        chosen = [f for f in frames if tag == "all" or f[0].startswith(tag + "/")]
        err = np.linalg.norm(np.stack([f[2] for f in chosen]) - np.stack([f[1] for f in chosen]), axis=2)
        assert rows[tag]["frames"] == len(chosen)
        assert rows[tag]["m"]["ade_avg"] == pytest.approx(err.mean(), rel=1e-12)
        assert rows[tag]["m"]["fde"] == pytest.approx(err[:, 5].mean(), rel=1e-12)


def test_history_bias_separates_carry_over_from_straight(tmp_path):
    frames_follow, frames_straight = [], []
    for i, k in enumerate((-0.06, -0.04, 0.05, 0.07)):
        hist = history(8.0, (0, k, k, k, k, k))
        gt = drive(8.0)  # the truth goes straight after the turn
        frames_follow.append((f"f{i}", gt, drive(8.0, k), hist))  # keeps turning: history bias
        frames_straight.append((f"f{i}", gt, drive(8.0), hist))
    follow = write_run(tmp_path, "follower", frames_follow)
    straight = write_run(tmp_path, "straight", frames_straight)
    stats = {s["model"]: s for s in history_bias([follow, straight])}
    assert stats["follower"]["after_turn_frames"] == 4
    assert stats["follower"]["carry_pred"] == pytest.approx(1.0, rel=1e-2)
    assert stats["follower"]["slope_pred"] == pytest.approx(1.0, rel=1e-2)
    assert stats["straight"]["carry_pred"] == pytest.approx(0.0, abs=1e-9)
    assert stats["follower"]["carry_true"] == pytest.approx(0.0, abs=1e-9)


def test_disagreement_and_worst_frames(tmp_path):
    gt, hist = CASES["cruising"]
    frames_a = [(f"f{i}", gt, gt, hist, f"scene-{i}") for i in range(5)]
    frames_b = [(f"f{i}", gt, gt + [0.0, 0.5 * i], hist, f"scene-{i}") for i in range(5)]
    frames_b[2] = ("f2", gt, gt + [0.0, 9.0], hist, "scene-2")  # the big disagreement
    a, b = write_run(tmp_path, "a", frames_a), write_run(tmp_path, "b", frames_b)
    top = disagreements([a, b], top=2)
    assert [t["frame_id"] for t in top] == ["f2", "f4"]
    assert top[0]["spread_m"] == pytest.approx(9.0) and top[0]["fde"] == {"a": 0.0, "b": pytest.approx(9.0)}
    worst = worst_frame_per_tag([a, b], tags=("cruising",))
    assert worst == [{"tag": "cruising", "frame_id": "f2", "mean_fde": pytest.approx(4.5), "frames_with_tag": 5}]


def test_disagreements_pick_distinct_scenes_a_minimum_spread_and_name_the_models(tmp_path):
    """Before: five consecutive keyframes of one scene, and frames where the models agree ("disagree by 0.0 m")."""
    gt, hist = CASES["cruising"]
    spreads = [6.0, 5.0, 4.0, 0.4, 0.0, 3.0]
    scenes = ["s1", "s1", "s1", "s2", "s3", "s4"]
    frames_a = [(f"f{i}", gt, gt, hist, sc) for i, sc in enumerate(scenes)]
    frames_b = [(f"f{i}", gt, gt + [0.0, d], hist, sc) for i, (d, sc) in enumerate(zip(spreads, scenes))]
    a, b = write_run(tmp_path, "a", frames_a), write_run(tmp_path, "b", frames_b)
    cv = write_run(tmp_path, "baseline:cv", [(f"f{i}", gt, gt + [0.0, -20.0], hist, sc) for i, sc in enumerate(scenes)])
    top = disagreements([a, b, cv], top=5)
    assert [t["frame_id"] for t in top] == ["f0", "f5"]  # one per scene; s2 and s3 agree within 1 m
    assert [t["scene"] for t in top] == ["s1", "s4"] and all(t["spread_m"] >= 1.0 for t in top)
    assert all(t["models"] == ["a", "b"] for t in top)  # the baseline is not compared: not counted in the number
    assert top[0]["spread_m"] == pytest.approx(6.0)


def test_scenarios_need_history(tmp_path):
    run = write_run(tmp_path, "m", [("f", *CASES["cruising"][:1], CASES["cruising"][0], CASES["cruising"][1])])
    run.history_actions = None
    with pytest.raises(ValueError, match="details=True"):
        per_tag_metrics([run])
