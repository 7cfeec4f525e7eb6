"""`lightemma report`: one folder with an index linking tables and figures that exist and show something."""

from __future__ import annotations

import os
import re

os.environ.setdefault("MPLBACKEND", "Agg")

import numpy as np
import pytest
from PIL import Image

from lightemma.cli import main
from lightemma.evaluation.synthetic import write_synthetic_run
from lightemma.report import write_report


def n_colours(img: np.ndarray) -> int:
    """Distinct RGB colours of an (H, W, 3) uint8 image."""
    packed = (img[..., 0].astype(np.int32) << 16) | (img[..., 1].astype(np.int32) << 8) | img[..., 2]
    return len(np.unique(packed))


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    runs = tmp_path_factory.mktemp("runs")
    write_synthetic_run(runs, "openai/gpt-4o", 60, seed=1, noise=0.3)
    write_synthetic_run(runs, "gemini/gemini-2.0-flash", 60, seed=2, noise=0.8)
    write_synthetic_run(
        runs,
        "baseline:cv",
        60,
        seed=3,
        noise=1.5,
        manifest={"dataset": {"dataroot": str(runs / "nowhere"), "version": "v1.0-mini", "split": "all"}},
    )
    out = tmp_path_factory.mktemp("report")
    index = write_report([runs], out, top=1, common=True, svg=True)
    return out, index, index.read_text()


def test_index_links_only_files_that_exist(report):
    out, index, text = report
    links = re.findall(r"\]\(([^)]+)\)", text)
    assert len(links) >= 12
    for link in links:
        assert (out / link).is_file(), link
    for name in ("efficiency", "accuracy_lightemma", "accuracy_stp3", "accuracy_uniad"):
        assert (out / "tables" / f"{name}.csv").is_file() and (out / "tables" / f"{name}.tex").is_file()
    assert (out / "tables" / "evaluation.json").is_file()


def test_index_has_tables_scenarios_and_pictures(report):
    out, index, text = report
    assert "| GPT-4o |" in text and "| Gemini-2.0-Flash |" in text and "| GPT-4o (paper) |" in text
    assert "frames scored in every run" in text
    assert "### ADE avg by scenario tag" in text and "| braking |" in text
    assert re.search(r"per scenario tag, on the \d+ frames scored in every run", text)
    assert "History bias" in text
    assert "models shown disagree by" in text and "worst `braking` frame" in text
    # the dataset named in a manifest is not there: said once, pictures still drawn (bird's-eye only)
    assert "pictures have no camera view" in text
    grids = sorted((out / "figures" / "frames").glob("*_grid.png"))
    assert grids


def test_report_figures_are_not_blank(report):
    out, index, text = report
    for png in [
        out / "figures" / "bubble.png",
        out / "figures" / "history_bias.png",
        *sorted((out / "figures" / "frames").glob("*.png"))[:3],
    ]:
        img = np.asarray(Image.open(png).convert("RGB"))
        assert img.shape[0] > 200 and img.shape[1] > 300
        assert n_colours(img) > 20, png
        assert (png.with_suffix(".svg")).stat().st_size > 1000


def test_cli_report_and_its_errors(tmp_path, capsys):
    runs = tmp_path / "runs"
    write_synthetic_run(runs, "openai/gpt-4o", 12)
    assert main(["report", str(runs), "--out", str(tmp_path / "rep"), "--no-pictures", "--no-paper"]) == 0
    assert f"report written to {tmp_path / 'rep' / 'index.md'}" in capsys.readouterr().out
    text = (tmp_path / "rep" / "index.md").read_text()
    assert "(paper)" not in text and "figures/frames" not in text
    assert main(["report", str(tmp_path / "missing"), "--out", str(tmp_path / "rep2")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("lightemma report: error:") and "does not exist" in err and "\n" not in err


def test_pictures_use_the_camera_of_the_runs_dataset(tmp_path):
    """Runs made on a (synthetic) nuScenes dataset: pictures get its CAM_FRONT image and calibration."""
    import lightemma
    from lightemma.backends.baseline import baseline_actions
    from lightemma.evaluation import load_run
    from lightemma.evaluation.synthetic import make_record
    from lightemma.report.pictures import CameraSource
    from lightemma.runs.store import RunWriter, create_run_dir
    from lightemma.synth import write_dataset

    root = write_dataset(tmp_path / "data", scenes=8, keyframes=15, image_size=(320, 180), sweeps=False)
    frames = lightemma.load_frames(root, "v1.0-mini", split="all")
    run_dirs = []
    for kind in ("constant", "cv"):
        run_dir = create_run_dir(
            tmp_path / "runs",
            f"baseline:{kind}",
            {"model": f"baseline:{kind}", "dataset": frames.describe(), "finished_at": "t"},
        )
        with RunWriter(run_dir) as w:
            for frame in frames:
                actions = baseline_actions(kind, frame)
                w.append(
                    make_record(
                        frame.frame_id,
                        frame.gt_positions,
                        lightemma.integrate(actions),
                        actions=actions,
                        history_actions=frame.history_actions,
                    )
                )
        run_dirs.append(run_dir)
    runs = [load_run(d, details=True) for d in run_dirs]
    cameras = CameraSource().cameras(runs, frames.frame_ids[:3])
    for fid, camera in cameras.items():
        assert camera is not None and camera.image.shape == (180, 320, 3), fid
        np.testing.assert_allclose(camera.intrinsic, frames[frames.frame_ids.index(fid)].camera_intrinsic)
    index = write_report(run_dirs, tmp_path / "report", top=1, convention="lightemma", case_tags=())
    text = index.read_text()
    assert "no camera view" not in text and "figures/frames/" in text
    grid = next((tmp_path / "report" / "figures" / "frames").glob("disagree_*_grid.png"))
    assert n_colours(np.asarray(Image.open(grid).convert("RGB"))) > 200  # a photo-like image, not flat panels


def test_report_of_a_run_without_frames(tmp_path):
    from lightemma.runs.store import create_run_dir

    create_run_dir(tmp_path / "runs", "openai/gpt-4o", {"model": "openai/gpt-4o"})
    text = write_report([tmp_path / "runs"], tmp_path / "rep", with_paper=False).read_text()
    assert "No model has a scored frame yet" in text and "no frames to evaluate" in text


def test_public_names():
    import lightemma

    assert lightemma.evaluate_runs is __import__("lightemma.evaluation", fromlist=["x"]).evaluate_runs
    assert callable(lightemma.write_report) and callable(lightemma.run_demo)


def test_requested_frames_are_drawn_and_unknown_ones_refused(tmp_path, capsys):
    runs = tmp_path / "runs"
    write_synthetic_run(runs, "openai/gpt-4o", 12)
    write_synthetic_run(runs, "baseline:cv", 12, noise=1.0)
    assert (
        main(
            [
                "report",
                str(runs),
                "--out",
                str(tmp_path / "rep"),
                "--frame",
                "scene-0000/9",
                "--top",
                "0",
                "--convention",
                "lightemma",
            ]
        )
        == 0
    )
    text = (tmp_path / "rep" / "index.md").read_text()
    assert re.search(r"\*\*requested frame[^*]*\*\* — frame `scene-0000/9`", text)
    (grid,) = (tmp_path / "rep" / "figures" / "frames").glob(
        "frame_scene-0000_9_*grid.png"
    )  # readable, then a hash of the id
    assert re.fullmatch(r"frame_scene-0000_9_[0-9a-f]{10}_grid\.png", grid.name)
    capsys.readouterr()
    assert main(["report", str(runs), "--out", str(tmp_path / "rep2"), "--frame", "nope/1"]) == 2
    assert "frame(s) not in any run: nope/1" in capsys.readouterr().err


def test_a_frame_picked_twice_is_drawn_once():
    from lightemma.report.writer import _merge_picks

    picks = [("disagree", "a", "spread"), ("case", "b", "worst braking"), ("case", "a", "worst starting")]
    assert _merge_picks(picks) == [("disagree", "a", "spread; worst starting"), ("case", "b", "worst braking")]


def test_a_negative_top_is_an_error_not_every_frame_but_one(tmp_path, capsys):
    """Before: --top -1 sliced [:-1] and drew every frame but one (828 files for 208 frames)."""
    runs = tmp_path / "runs"
    write_synthetic_run(runs, "openai/gpt-4o", 12)
    assert main(["report", str(runs), "--out", str(tmp_path / "rep"), "--top", "-1", "--no-paper"]) == 2
    assert capsys.readouterr().err.strip() == "lightemma report: error: --top must be 0 or more, got -1"
    assert not (tmp_path / "rep").exists()
