"""The report's figures as a new user meets them (issue 24, item 3): one test per fault found."""

from __future__ import annotations

import colorsys
import os
import re

os.environ.setdefault("MPLBACKEND", "Agg")

import numpy as np
import pytest
from PIL import Image

from lightemma.cli import main
from lightemma.evaluation.synthetic import write_synthetic_run
from lightemma.report import write_report
from lightemma.report.figures import Camera, frame_figure, history_bias_figure, model_grid, pairwise_figure, save_figure
from lightemma.report.figures._mpl import FAMILY_COLORS, GT_COLOR, model_colors

K = np.array([[1266.4, 0.0, 816.3], [0.0, 1266.4, 491.5], [0.0, 0.0, 1.0]])
EXTRINSIC = np.eye(4)
EXTRINSIC[:3, :3] = [[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]
EXTRINSIC[:3, 3] = [1.70, 0.016, 1.51]
STEPS = np.arange(1, 7) * 0.5


def _hue(color: str) -> float:
    return colorsys.rgb_to_hls(*(int(color[i : i + 2], 16) / 255 for i in (1, 3, 5)))[0] * 360


def _hue_gap(a: float, b: float) -> float:
    return min(abs(a - b), 360 - abs(a - b))


def _boxes_overlap(a, b) -> bool:
    return a.x0 < b.x1 and b.x0 < a.x1 and a.y0 < b.y1 and b.y0 < a.y1


@pytest.mark.parametrize("labels", [["GPT-4o", "Gemini-2.0-Flash"], ["GPT-4o", "Claude-3.7-Sonnet", "Qwen-2.5-VL-7B"]])
def test_pairwise_title_and_colourbar_label_stay_inside_and_apart(labels):
    rows = [
        {"model_a": a, "model_b": b, "ade_avg_diff": 0.1 * (i + 1), "significant": i % 2 == 0}
        for i, (a, b) in enumerate((a, b) for k, a in enumerate(labels) for b in labels[k + 1 :])
    ]
    fig = pairwise_figure(rows, labels)
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    figure_box = fig.bbox
    title = fig._suptitle.get_window_extent(renderer)
    bar_label = fig.axes[-1].yaxis.label.get_window_extent(renderer)
    for box in (title, bar_label):
        assert (
            figure_box.x0 <= box.x0 and box.x1 <= figure_box.x1 and figure_box.y0 <= box.y0 and box.y1 <= figure_box.y1
        )
    assert not _boxes_overlap(title, bar_label)


def test_baselines_are_cyan_and_two_runs_of_one_model_differ():
    models = [
        {"label": "GPT-4o", "family": "GPT", "generation": 1},
        {"label": "GPT-4o [conversation]", "family": "GPT", "generation": 1},  # a second run of one model
        {"label": "LLaMA-3.2-11B", "family": "LLaMA", "generation": 1},
        {"label": "Claude-3.7-Sonnet", "family": "Claude", "generation": 1},
        *({"label": f"baseline:{k}", "family": "Baseline"} for k in ("constant", "cv", "ca", "last")),
        {"label": "my-vlm", "family": "Other"},
        {"label": "your-vlm", "family": "Other"},
    ]
    colors = model_colors(models)
    assert len(set(colors.values())) == len(models) and GT_COLOR not in colors.values()
    cyan = _hue(FAMILY_COLORS["Baseline"])
    for label in ("baseline:constant", "baseline:cv", "baseline:ca", "baseline:last"):
        assert _hue_gap(_hue(colors[label]), cyan) < 8, label  # every baseline a shade of the legend's cyan
    families = [FAMILY_COLORS[f] for f in ("GPT", "Claude", "Gemini", "Qwen", "LLaMA")]
    for label in ("baseline:constant", "baseline:cv", "baseline:ca", "baseline:last", "my-vlm", "your-vlm"):
        r, g, b = (int(colors[label][i : i + 2], 16) / 255 for i in (1, 3, 5))
        saturated = colorsys.rgb_to_hls(r, g, b)[2] > 0.25
        assert not saturated or all(_hue_gap(_hue(colors[label]), _hue(f)) > 20 for f in families), (
            label
        )  # no family's hue
    # the bubble chart's legend shows the baselines' cyan
    from lightemma.report.figures import bubble_chart

    points = [
        {
            "model": m["label"],
            "family": m["family"],
            "generation": m.get("generation"),
            "ade_avg": 1.0 + i / 10,
            "seconds_per_frame": 1.0,
            "source": "lightemma",
        }
        for i, m in enumerate(models)
    ]
    fig = bubble_chart(points)
    legend = fig.axes[0].get_legend()
    swatch = next(h for h, t in zip(legend.legend_handles, legend.get_texts()) if t.get_text() == "Baseline")
    assert _hue_gap(_hue(_hex(swatch.get_color())), cyan) < 8


def _hex(color) -> str:
    from matplotlib.colors import to_hex

    return to_hex(color)


def _count(img: np.ndarray, color: str, tol: int = 40) -> int:
    rgb = np.array([int(color[i : i + 2], 16) for i in (1, 3, 5)])
    return int((np.abs(img.astype(int) - rgb).sum(axis=2) <= tol).sum())


def test_a_prediction_on_the_ground_truth_stays_visible(tmp_path):
    image = np.full((900, 1600, 3), 60, dtype=np.uint8)
    gt = np.stack([7.0 * STEPS, 0.4 * STEPS**2], axis=1)
    color = "#7048c8"
    counts = []
    for name, truth in (
        ("alone", gt + [0.0, 60.0]),
        ("on_truth", gt),
    ):  # ground truth far off-image, then exactly under the prediction
        fig = frame_figure(truth, {"m": gt}, camera=Camera(image, K, EXTRINSIC), colors={"m": color})
        (png,) = save_figure(fig, tmp_path / name, formats=("png",))
        counts.append(_count(np.asarray(Image.open(png).convert("RGB")), color))
    alone, on_truth = counts
    assert on_truth >= 0.6 * alone  # the ground truth (thin, dashed) leaves most of the prediction in view
    assert _count(np.asarray(Image.open(tmp_path / "on_truth.png").convert("RGB")), GT_COLOR) > 100  # and shows itself


def test_grid_birds_eye_views_have_units_and_never_cover_the_camera_image():
    gt = np.stack([6.0 * STEPS, 0.2 * STEPS**2], axis=1)
    preds = {f"model {i}": gt + [0.0, 0.6 * i] for i in range(4)}
    fig = model_grid(gt, preds, camera=Camera(np.full((900, 1600, 3), 90, dtype=np.uint8), K, EXTRINSIC), title="f")
    fig.canvas.draw()
    cams = [ax for ax in fig.axes if ax.images]
    bevs = [ax for ax in fig.axes if not ax.images and ax.get_xlabel()]
    assert len(cams) == 4 and len(bevs) == 4
    for bev in bevs:
        assert "(m)" in bev.get_xlabel() and "(m)" in bev.get_ylabel()
        for cam in cams:
            assert not _boxes_overlap(bev.get_window_extent(), cam.get_window_extent())


def _bias_runs(tmp_path):
    """Run 0 covers two frames only; run 1 all, with frames going straight just after a turn; run 2 none of those."""
    from tests.unit.evaluation.test_scenarios import CASES, write_run

    frames = []
    rng = np.random.default_rng(0)
    for rep in range(12):
        for name in ("straight_after_left_turn", "turning_left", "turning_right", "cruising"):
            gt, hist = CASES[name]
            frames.append((f"{name}/{rep}", gt, gt + rng.normal(0, 0.2, (6, 2)), hist, f"{name}-{rep}"))
    few = write_run(tmp_path, "few-frames", frames[:2])
    full = write_run(tmp_path, "full", frames)
    no_turns = write_run(tmp_path, "no-turns", [f for f in frames if not f[0].startswith("straight_after")])
    return [few, full, no_turns]


def test_history_bias_keeps_every_model_and_its_truth_line(tmp_path):
    runs = _bias_runs(tmp_path)
    fig = history_bias_figure(runs)
    scatter, slopes, bars = fig.axes[:3]
    assert any(t.get_text().startswith("truth: slope") for t in scatter.get_legend().get_texts())
    assert any(t.get_text().startswith("truth (") for t in bars.get_legend().get_texts())
    names = lambda ax: [t.get_text().split(" (n=")[0] for t in ax.get_yticklabels()]  # noqa: E731
    assert sorted(names(slopes)) == sorted(names(bars)) == ["few-frames", "full", "no-turns"]
    assert any("no frame straight just after a turn" in t.get_text() for t in bars.texts)


@pytest.mark.parametrize("n_models", [1, 13])
def test_history_bias_panels_are_filled_and_their_labels_apart(tmp_path, n_models):
    runs = []
    for i in range(n_models):
        runs.append(write_synthetic_run(tmp_path / "runs", f"openai/gpt-4o-{i}", 80, seed=i, noise=0.2 + 0.05 * i))
    from lightemma.evaluation import load_run

    loaded = [load_run(r, details=True) for r in runs]
    fig = history_bias_figure(loaded)
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    for ax in fig.axes[1:3]:
        low, high = ax.get_ylim()
        assert high - low <= n_models + 0.5  # no empty band: rows fill the panel
        boxes = [t.get_window_extent(renderer) for t in ax.get_yticklabels() if t.get_text()]
        assert len(boxes) == n_models
        for a, b in zip(boxes, boxes[1:]):
            assert not _boxes_overlap(a, b)


@pytest.fixture(scope="module")
def disagreement_report(tmp_path_factory):
    runs = tmp_path_factory.mktemp("runs")
    write_synthetic_run(runs, "openai/gpt-4o", 104, seed=1, noise=0.2)
    write_synthetic_run(runs, "gemini/gemini-2.0-flash", 104, seed=2, noise=1.0)
    write_synthetic_run(runs, "baseline:cv", 104, seed=3, noise=6.0)  # far off everywhere: never counted in the spread
    from lightemma.runs.store import create_run_dir

    create_run_dir(
        runs, "anthropic/claude-3-7-sonnet-20250219", {"model": "anthropic/claude-3-7-sonnet-20250219"}
    )  # an aborted, empty run
    return runs


def test_disagreement_pictures_show_the_models_their_number_was_measured_on(disagreement_report, tmp_path, monkeypatch):
    import lightemma.report.figures as figures

    drawn = []
    real = figures.model_grid

    def spy(gt, predictions, **kwargs):
        drawn.append((kwargs.get("title"), {k: np.asarray(v) for k, v in predictions.items()}))
        return real(gt, predictions, **kwargs)

    monkeypatch.setattr(figures, "model_grid", spy)
    text = write_report(
        [disagreement_report], tmp_path / "rep", top=3, case_tags=(), with_paper=False, pictures=True
    ).read_text()
    captions = re.findall(r"the (\d+) models shown disagree by ([\d.]+) m at 3 s", text)
    assert len(captions) == 3
    scenes = set()
    for (title, preds), (count, spread) in zip(drawn, captions):
        assert sorted(preds) == ["GPT-4o", "Gemini-2.0-Flash"] and int(count) == 2
        ends = np.stack([p[-1] for p in preds.values()])
        assert float(np.linalg.norm(ends[0] - ends[1])) == pytest.approx(float(spread), abs=0.051)
        assert float(spread) >= 1.0
        scenes.add(title.split("/")[0])
    assert len(scenes) == 3  # three different scenes, not consecutive keyframes of one


def test_an_empty_run_is_left_out_with_a_warning_not_every_picture(disagreement_report, tmp_path, capsys, monkeypatch):
    import sys

    monkeypatch.setattr(sys.stderr, "isatty", lambda: True)  # a terminal: the progress bar is drawn
    assert main(["report", str(disagreement_report), "--out", str(tmp_path / "rep"), "--top", "2", "--no-paper"]) == 0
    err = capsys.readouterr().err
    text = (tmp_path / "rep" / "index.md").read_text()
    assert re.search(r"left out .*claude-3-7-sonnet.*: no scored frame \(an empty or aborted run\)", text)
    assert "Claude" not in text.split("## Tables I and II")[1].split("## Frames")[0]  # no empty rows in the tables
    assert list((tmp_path / "rep" / "figures" / "frames").glob("disagree_*_grid.png"))
    # the long steps show progress (tqdm on stderr)
    assert "report:" in err and "frame pictures" in err
    monkeypatch.setattr(sys.stderr, "isatty", lambda: False)  # a log file or a pipe: no bar and its \r redraws
    assert main(["report", str(disagreement_report), "--out", str(tmp_path / "rep2"), "--top", "2", "--no-paper"]) == 0
    err = capsys.readouterr().err
    assert not re.search(r"(?<!lightemma )report:", err) and "frame pictures" not in err and "\r" not in err  # no bar
    assert re.search(
        r"lightemma report: warning: left out .*claude-3-7-sonnet.*: no scored frame", err
    )  # the warning, on stderr too
