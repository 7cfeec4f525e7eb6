"""Figures are drawn, saved as PNG and SVG, and show what they should (pixels, not just files)."""

from __future__ import annotations

import os

os.environ.setdefault("MPLBACKEND", "Agg")

import numpy as np
import pytest
from PIL import Image

from lightemma.evaluation import evaluate_runs, load_run
from lightemma.evaluation.synthetic import write_synthetic_run
from lightemma.report.figures import (
    Camera,
    bubble_chart,
    bubble_points,
    frame_figure,
    history_bias_figure,
    model_grid,
    project,
    save_figure,
)
from lightemma.report.figures._mpl import GT_COLOR, family_color, pred_color

# a nuScenes-like CAM_FRONT: 1600×900, f = 1266 px, 1.70 m ahead of the rear axle, 1.51 m up
K = np.array([[1266.4, 0.0, 816.3], [0.0, 1266.4, 491.5], [0.0, 0.0, 1.0]])
EXTRINSIC = np.eye(4)
EXTRINSIC[:3, :3] = [[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]  # camera z forward, x right, y down
EXTRINSIC[:3, 3] = [1.70, 0.016, 1.51]
STEPS = np.arange(1, 7) * 0.5


def rgb(hex_color: str) -> np.ndarray:
    return np.array([int(hex_color[i : i + 2], 16) for i in (1, 3, 5)])


def pixels(path) -> np.ndarray:
    return np.asarray(Image.open(path).convert("RGB")).astype(int)


def near(img: np.ndarray, color: np.ndarray, tol: int = 30) -> np.ndarray:
    return np.abs(img - color).sum(axis=2) <= tol


def test_projection_matches_pinhole_by_hand():
    uv, visible = project(np.array([[10.0, 0.0], [20.0, 2.0], [-5.0, 0.0]]), K, EXTRINSIC)
    # by hand: camera coords of (10, 0, 0) are (0.016, 1.51, 8.3)
    assert uv[0] == pytest.approx([816.3 + 1266.4 * 0.016 / 8.3, 491.5 + 1266.4 * 1.51 / 8.3])
    assert uv[1] == pytest.approx([816.3 + 1266.4 * (0.016 - 2.0) / 18.3, 491.5 + 1266.4 * 1.51 / 18.3])
    assert visible.tolist() == [True, True, False] and np.isnan(uv[2]).all()


def _frame_png(tmp_path, *, texts=None):
    image = np.full((900, 1600, 3), 60, dtype=np.uint8)
    image[:400] = (150, 180, 210)
    gt = np.stack([8.0 * STEPS, 0.6 * STEPS**2], axis=1)  # drifting left
    pred = np.stack([7.0 * STEPS, -0.8 * STEPS**2], axis=1)  # drifting right
    fig = frame_figure(gt, {"model A": pred}, camera=Camera(image, K, EXTRINSIC), texts=texts, title="scene-0001/7")
    fig.canvas.draw()
    ax = fig.axes[0]
    to_pixels = lambda pts: ax.transData.transform(project(pts, K, EXTRINSIC)[0])  # noqa: E731
    gt_px, pred_px = to_pixels(gt), to_pixels(pred)
    height = fig.get_size_inches()[1] * fig.dpi
    paths = save_figure(fig, tmp_path / "frame", dpi=fig.dpi)
    return paths, gt_px, pred_px, height


def test_frame_picture_draws_trajectories_where_they_project(tmp_path):
    paths, gt_px, pred_px, height = _frame_png(
        tmp_path, texts={"scene": "cars ahead", "intent": "keep lane", "answer": "[(8.0, 0.0)]"}
    )
    assert [p.suffix for p in paths] == [".png", ".svg"] and all(p.stat().st_size > 1000 for p in paths)
    img = pixels(paths[0])
    assert len(np.unique(img.reshape(-1, 3), axis=0)) > 50  # not a blank canvas
    assert near(img, np.array([150, 180, 210]), 6).sum() > 10000  # the camera image is there
    for points, color in ((gt_px, GT_COLOR), (pred_px, pred_color(0))):
        hits = 0
        for x, y in points[2:5]:  # 1.5–2.5 s, well inside the image
            row, col = int(round(height - y)), int(round(x))
            window = img[row - 6 : row + 7, col - 6 : col + 7]
            hits += near(window, rgb(color)).any()
        assert hits == 3, f"{color} not found at its projected points"
    # ground truth drifts left, prediction right: their far points are on those sides
    assert gt_px[-1, 0] < pred_px[-1, 0]


def test_frame_picture_without_image_or_texts(tmp_path):
    gt = np.stack([5.0 * STEPS, np.zeros(6)], axis=1)
    fig = frame_figure(gt, {"m": gt + [0.0, 1.0]}, camera=Camera(None, K, EXTRINSIC))
    (png,) = save_figure(fig, tmp_path / "noimg", formats=("png",))
    img = pixels(png)
    assert near(img, np.array([200, 200, 200]), 3).sum() > 10000  # grey placeholder canvas
    assert near(img, rgb(GT_COLOR)).sum() > 100 and near(img, rgb(pred_color(0))).sum() > 100


def test_model_grid_has_one_colour_per_model(tmp_path):
    gt = np.stack([6.0 * STEPS, 0.2 * STEPS**2], axis=1)
    preds = {f"model {i}": gt + [0.0, 0.8 * (i + 1)] for i in range(4)}
    fig = model_grid(gt, preds, camera=Camera(None, K, EXTRINSIC), title="frame", errors={"model 0": 0.8})
    assert len([ax for ax in fig.axes if ax.get_title().startswith("model")]) == 4
    (png,) = save_figure(fig, tmp_path / "grid", formats=("png",))
    img = pixels(png)
    for i in range(4):
        assert near(img, rgb(pred_color(i))).sum() > 50, i
    assert near(img, rgb(GT_COLOR)).sum() > 200


def test_bubble_area_follows_time_and_colour_follows_family(tmp_path):
    points = [
        {"model": "fast", "family": "GPT", "ade_avg": 1.0, "seconds_per_frame": 1.0},
        {"model": "slow", "family": "LLaMA", "ade_avg": 1.5, "seconds_per_frame": 20.0},
    ]
    paths = save_figure(bubble_chart(points), tmp_path / "bubble")
    img = pixels(paths[0])
    white = np.array([255, 255, 255])
    blended = lambda c: 0.75 * rgb(c) + 0.25 * white  # noqa: E731  (alpha 0.75 on white)
    fast, slow = near(img, blended(family_color("GPT")), 20).sum(), near(img, blended(family_color("LLaMA")), 20).sum()
    assert fast > 20 and slow > 5 * fast
    assert paths[1].read_text().lstrip().startswith("<?xml") and "<svg" in paths[1].read_text()


def test_bubble_points_from_evaluation_and_paper(tmp_path):
    write_synthetic_run(tmp_path, "openai/gpt-4o", 20)
    write_synthetic_run(tmp_path, "baseline:cv", 20, noise=1.0)
    points = bubble_points(evaluate_runs([tmp_path]), with_paper=True)
    assert len(points) == 2 + 15
    assert sum(p.get("source") == "paper" for p in points) == 15
    fig = bubble_chart(points)
    labels = [t.get_text() for t in fig.axes[0].get_xticklabels()]
    # families grouped in the paper's order, generations in order, baseline last
    assert labels.index("GPT-4o") < labels.index("GPT-5.2 (paper)") < labels.index("Claude-3.7-Sonnet (paper)")
    assert labels[-1] == "baseline:cv"
    with pytest.raises(ValueError, match="no model has an ADE"):
        bubble_chart([{"model": "x", "family": "GPT", "ade_avg": None}])


def test_history_bias_figure_is_drawn(tmp_path):
    """A model that keeps turning after the turn ended: its points and bar are red, the truth green."""
    import lightemma
    from lightemma.evaluation.synthetic import make_record
    from lightemma.runs.store import RunWriter, create_run_dir

    run_dir = create_run_dir(tmp_path, "m", {"model": "m", "finished_at": "t"})
    straight = np.stack([8.0 * STEPS, np.zeros(6)], axis=1)
    with RunWriter(run_dir) as w:
        for i, k in enumerate(np.linspace(-0.08, 0.08, 40)):
            pred = lightemma.integrate(np.array([[8.0, k]] * 6), method="midpoint")
            hist = np.array([[8.0, k]] * 6)
            w.append(make_record(f"f{i}", straight, pred, history_actions=hist))
    fig = history_bias_figure([load_run(run_dir, details=True)])
    scatter, slopes, bars = fig.axes
    assert len(bars.patches) == 1 and bars.patches[0].get_width() == pytest.approx(1.0, rel=0.02)
    assert [t.get_text() for t in slopes.get_yticklabels()] == ["m"]  # one slope with its interval per model
    (png,) = save_figure(fig, tmp_path / "bias", formats=("png",))
    img = pixels(png)
    assert near(img, rgb(GT_COLOR), 40).sum() > 100 and near(img, rgb(pred_color(0)), 40).sum() > 500


def test_history_bias_figure_draws_ablated_runs_beside_the_full_ones(tmp_path):
    """An ablation run is drawn just after its model's full run, in the same colour, hollow, with its own marker."""
    import matplotlib.colors as mcolors

    import lightemma
    from lightemma.evaluation.synthetic import make_record
    from lightemma.report.figures.history_bias import INPUT_MARKERS
    from lightemma.runs.store import RunWriter, create_run_dir

    straight = np.stack([8.0 * STEPS, np.zeros(6)], axis=1)
    runs = []
    for model, inputs, gain in (("m", "full", 1.0), ("other", "full", 0.2), ("m", "no-image", 0.5)):
        run_dir = create_run_dir(tmp_path, model, {"model": model, "finished_at": "t", "config": {"inputs": inputs}})
        with RunWriter(run_dir) as w:
            for i, k in enumerate(np.linspace(-0.08, 0.08, 40)):
                pred = lightemma.integrate(np.array([[8.0, gain * k]] * 6), method="midpoint")
                w.append(make_record(f"f{i}", straight, pred, history_actions=np.array([[8.0, k]] * 6)))
        runs.append(load_run(run_dir, details=True))
    fig = history_bias_figure(runs)
    scatter, slopes, bars = fig.axes
    assert [t.get_text() for t in slopes.get_yticklabels()] == ["m", "m [no-image]", "other"]
    points = [line for line in slopes.lines if line.get_marker() in INPUT_MARKERS.values()]
    assert [p.get_marker() for p in points] == ["o", "s", "o"]  # top to bottom as the labels
    full, ablated = points[0], points[1]
    assert mcolors.to_hex(full.get_color()) == mcolors.to_hex(ablated.get_color())
    assert mcolors.to_hex(ablated.get_markerfacecolor()) == "#ffffff" != mcolors.to_hex(full.get_markerfacecolor())
    assert [p.get_hatch() for p in bars.patches] == [None, "//", None]


def test_ablation_figure_draws_each_comparison_with_its_interval_filled_when_significant(tmp_path):
    from lightemma.report.figures import ablation_figure

    ablations = [
        {
            "model": "m",
            "ablation": "no-image",
            "ade_avg_diff": -0.4,
            "ade_avg_ci95": [-0.6, -0.2],
            "ade_avg_significant": True,
        },
        {
            "model": "m",
            "ablation": "blank-image",
            "ade_avg_diff": 0.01,
            "ade_avg_ci95": [-0.1, 0.12],
            "ade_avg_significant": False,
        },
    ]
    gains = [
        {
            "model": "m",
            "baseline": "Baseline (ego status)",
            "ade_avg_gain": 0.3,
            "ade_avg_ci95": None,
            "ade_avg_significant": False,
        }
    ]
    fig = ablation_figure(ablations, gains)
    left, right = fig.axes
    assert [t.get_text() for t in left.get_yticklabels()] == ["m − no-image", "m − blank-image"]
    points = [line for line in left.lines if line.get_marker() == "o"]
    assert [p.get_xdata()[0] for p in points] == [-0.4, 0.01]
    assert points[0].get_markerfacecolor() != points[1].get_markerfacecolor()  # filled: significant; hollow: not
    assert [t.get_text() for t in right.get_yticklabels()] == ["m vs Baseline (ego status)"]
    (png,) = save_figure(fig, tmp_path / "ablations", formats=("png",))
    assert png.stat().st_size > 1000
    assert len(ablation_figure([], gains).axes) == 1
    with pytest.raises(ValueError, match="no ablation"):
        ablation_figure([], [])


def test_saved_as_150_dpi_png_and_svg_even_with_a_dot_in_the_name(tmp_path):
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(4, 3))
    png, svg = save_figure(fig, tmp_path / "frames" / "case_Gemini-2.5-Flash")
    assert (png.name, svg.name) == ("case_Gemini-2.5-Flash.png", "case_Gemini-2.5-Flash.svg")
    assert Image.open(png).size == (600, 450)  # 4 × 3 in at 150 dpi


def test_birds_eye_view_holds_every_trajectory():
    from lightemma.report.figures.frame_view import bev_limits

    gt = np.stack([8.0 * STEPS, 0.0 * STEPS], axis=1)
    turning = np.stack([6.0 * np.sin(STEPS / 1.5) * 3, -9.0 * (1 - np.cos(STEPS / 1.5))], axis=1)  # a hard right turn
    behind = np.array([[-1.0, 0.5]] * 6)
    (h0, h1), (v0, v1) = bev_limits([gt, turning, behind])
    for traj in (gt, turning, behind, np.zeros((1, 2))):
        assert np.all((h0 < -traj[:, 1]) & (-traj[:, 1] < h1)) and np.all((v0 < traj[:, 0]) & (traj[:, 0] < v1))
    assert h1 - h0 == pytest.approx(v1 - v0)  # square: equal scale both ways


def test_one_colour_per_model_everywhere():
    from lightemma.report.figures._mpl import model_colors

    models = [
        {"model": "GPT-4o", "family": "GPT", "generation": 1},
        {"model": "GPT-5.2", "family": "GPT", "generation": 3},
        {"model": "Claude-3.7-Sonnet", "family": "Claude", "generation": 1},
        {"model": "baseline:cv", "family": "Baseline"},
        {"model": "baseline:constant", "family": "Baseline"},
        {"model": "my-vlm", "family": "Other"},
    ]
    colors = model_colors(models)
    assert len(set(colors.values())) == len(models)
    assert GT_COLOR not in colors.values()
    # the paper's GPT-4o row gets the run's colour; the colour does not depend on which other models are shown
    assert model_colors([{"model": "GPT-4o", "family": "GPT", "generation": 1}])["GPT-4o"] == colors["GPT-4o"]
    # a family reads as a family: both GPT shades share the hue
    import colorsys

    hue = lambda c: colorsys.rgb_to_hls(*(int(c[i : i + 2], 16) / 255 for i in (1, 3, 5)))[0]  # noqa: E731
    assert hue(colors["GPT-4o"]) == pytest.approx(hue(colors["GPT-5.2"]), abs=0.02)


def test_model_grid_uses_the_given_colours_and_has_a_legend(tmp_path):
    gt = np.stack([6.0 * STEPS, 0.2 * STEPS**2], axis=1)
    preds = {"A": gt + [0.0, 1.5], "B": gt + [0.0, -1.5]}
    colors = {"A": "#7048c8", "B": "#17becf"}
    fig = model_grid(gt, preds, camera=Camera(None, K, EXTRINSIC), colors=colors)
    legend = fig.legends[0]
    assert [t.get_text() for t in legend.get_texts()] == ["ground truth", "A", "B"]
    (png,) = save_figure(fig, tmp_path / "grid", formats=("png",))
    img = pixels(png)
    for color in colors.values():
        assert near(img, rgb(color)).sum() > 50, color


def test_bubble_axis_and_intervals_come_from_the_points_shown(tmp_path):
    points = [
        {
            "model": "a",
            "family": "GPT",
            "generation": 1,
            "ade_avg": 1.1,
            "ade_avg_ci95": [1.0, 1.2],
            "seconds_per_frame": 3.0,
        },
        {
            "model": "b",
            "family": "GPT",
            "generation": 2,
            "ade_avg": 1.4,
            "ade_avg_ci95": [1.3, 1.6],
            "seconds_per_frame": 5.0,
            "note": " (only 40 % scored)",
        },
        {"model": "a", "family": "GPT", "generation": 1, "ade_avg": 1.07, "seconds_per_frame": 12.0, "source": "paper"},
    ]
    fig = bubble_chart(points)
    ax = fig.axes[0]
    low, high = ax.get_ylim()
    assert 0.5 < low < 1.0 and 1.6 < high < 2.2
    assert [t.get_text() for t in ax.get_xticklabels()] == [
        "a",
        "b (only 40 % scored)",
    ]  # the paper's row shares a's slot
