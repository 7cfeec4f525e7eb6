"""Issue 32.13: every run in one figure has a colour of its own (per run, not per family), the truth drawn on top."""

from __future__ import annotations

import itertools
import json
import os

os.environ.setdefault("MPLBACKEND", "Agg")

import numpy as np
import pytest

from lightemma.evaluation.synthetic import write_synthetic_run
from lightemma.report import write_report
from lightemma.report.figures._mpl import (
    COLLISION_RED,
    GT_COLOR,
    MIN_DELTA_E,
    RUN_PALETTE,
    delta_e,
    run_colors,
    srgb_to_lab,
)


def test_cielab_matches_published_values():
    assert srgb_to_lab("#ffffff") == pytest.approx((100.0, 0.0, 0.0), abs=0.01)
    assert srgb_to_lab("#ff0000") == pytest.approx((53.24, 80.09, 67.20), abs=0.05)  # sRGB red, D65 (CIE 15)
    assert srgb_to_lab("#000000") == pytest.approx((0.0, 0.0, 0.0), abs=0.01)
    assert delta_e("#ff0000", "#ff0000") == 0.0


def test_every_pair_of_runs_in_one_figure_is_far_apart():
    labels = [f"run {k}" for k in range(len(RUN_PALETTE))]
    colors = run_colors(labels)
    assert len(set(colors.values())) == len(labels)
    for a, b in itertools.combinations(labels, 2):
        assert delta_e(colors[a], colors[b]) >= MIN_DELTA_E, (a, b, colors[a], colors[b])
    for c in colors.values():  # never the truth's green, the collision red or the white background
        assert min(delta_e(c, GT_COLOR), delta_e(c, COLLISION_RED), delta_e(c, "#ffffff")) >= MIN_DELTA_E, c
    assert run_colors(["a", "b", "a"]) == {"a": RUN_PALETTE[0], "b": RUN_PALETTE[1]}


def test_a_report_separates_runs_of_one_family(tmp_path):
    """Two GPT-4o runs and two baselines (one family each) get colours at least MIN_DELTA_E apart, used alike in
    the HTML frame browser, the bird's-eye views and the history-bias figure (all from one mapping)."""
    runs = tmp_path / "runs"
    write_synthetic_run(runs, "openai/gpt-4o", 24, seed=1, noise=0.3)
    write_synthetic_run(runs, "openai/gpt-4o", 24, seed=2, noise=0.5)
    write_synthetic_run(runs, "baseline:cv", 24, seed=3, noise=1.5)
    write_synthetic_run(runs, "baseline:constant", 24, seed=4, noise=1.0)
    out = tmp_path / "rep"
    write_report([runs], out, top=0, case_tags=(), pictures=False, with_paper=False, pairwise=False)
    data = (out / "html" / "data.js").read_text()
    models = json.loads(data[len("LE.data(") : data.rindex(")")])["models"]
    assert len(models) == 4
    for a, b in itertools.combinations(models, 2):
        assert delta_e(a["color"], b["color"]) >= MIN_DELTA_E, (a, b)


def _pixel(fig, transform, xy):
    """RGB (0–255) of the rendered figure at point ``xy`` under ``transform`` (to display pixels)."""
    fig.canvas.draw()
    img = np.asarray(fig.canvas.buffer_rgba())[..., :3]
    x, y = transform.transform(xy)
    return img[int(round(img.shape[0] - y)), int(round(x))]


def test_birds_eye_view_draws_the_truth_over_a_model_on_it(synth_root):
    """A model whose path is the ground truth's: at a truth waypoint the picture shows the truth's green, not the
    model's colour (the truth drawn last)."""
    from matplotlib.colors import to_rgb

    from lightemma.evaluation import safety as S
    from lightemma.nuscenes import load_frames
    from lightemma.report.figures.bev import bev_figure, bev_transform

    frames = load_frames(synth_root, "v1.0-mini")
    frame = frames[0]
    gt = np.asarray(frame.gt_positions, dtype=np.float64)
    fid = frame.frame_id if hasattr(frame, "frame_id") else f"{frame.scene_name}/{frame.sample_token}"
    data = S.load_safety_data(synth_root, "v1.0-mini")
    fig = bev_figure(fid, [("model", gt.copy(), "#1f77b4")], gt, data)
    ax = fig.axes[0]
    pose = data.poses[S.sample_token_of(fid)]
    path = S.ego_poses(gt[None], np.asarray([pose]))[0]
    rgb = _pixel(fig, bev_transform(pose) + ax.transData, path[2, :2])
    green = np.array(to_rgb(GT_COLOR)) * 255
    assert np.abs(rgb - green).max() < 40, rgb
