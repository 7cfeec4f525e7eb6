"""The report folder is written whole or not at all, never over a user's folder, and no image can crash it."""

from __future__ import annotations

import os
import signal
import struct
import subprocess
import sys
import time
import zlib

os.environ.setdefault("MPLBACKEND", "Agg")

import pytest

from lightemma.cli import main
from lightemma.evaluation.synthetic import write_synthetic_run
from lightemma.report import write_report


def _snapshot(folder):
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture()
def runs(tmp_path):
    runs = tmp_path / "runs"
    write_synthetic_run(runs, "openai/gpt-4o", 30, seed=1, noise=0.4)
    write_synthetic_run(runs, "baseline:cv", 30, seed=2, noise=1.2)
    return runs


def test_a_failed_report_leaves_the_old_one_whole(runs, tmp_path, monkeypatch):
    out = tmp_path / "rep"
    write_report([runs], out, top=1, pictures=False, with_paper=False)
    before = _snapshot(out)
    assert "index.md" in before and "index.html" in before and ".lightemma-report" in before

    import lightemma.report.html as html

    def boom(*args, **kwargs):
        raise RuntimeError("disk gone")

    monkeypatch.setattr(html, "write_html", boom)
    with pytest.raises(RuntimeError, match="disk gone"):
        write_report([runs], out, top=1, pictures=False)  # with the paper's rows: a different index.md
    assert _snapshot(out) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rep", "runs"]  # no hidden partial folder left


@pytest.mark.slow
def test_a_killed_report_leaves_the_old_one_whole_and_its_leftovers_go_next_time(runs, tmp_path):
    out = tmp_path / "rep"
    assert main(["report", str(runs), "--out", str(out), "--no-pictures", "--no-paper", "--top", "0"]) == 0
    before = _snapshot(out)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    proc = subprocess.Popen(
        [sys.executable, "-m", "lightemma", "report", str(runs), "--out", str(out), "--top", "3"],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        deadline = time.monotonic() + 120
        partial = []
        while time.monotonic() < deadline and proc.poll() is None:
            partial = [p for p in tmp_path.glob(".rep.partial-*") if (p / "tables").is_dir()]
            if partial:
                break
            time.sleep(0.05)
        assert partial, "the report never started writing its hidden folder"
        proc.send_signal(signal.SIGKILL)
        proc.wait(30)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert _snapshot(out) == before  # the old report, untouched, no 0-byte file in it
    assert partial[0].exists()
    assert main(["report", str(runs), "--out", str(out), "--no-pictures", "--top", "0"]) == 0
    assert not list(tmp_path.glob(".rep.*"))  # the dead report's leftovers are gone
    assert "(paper)" in (out / "index.md").read_text()


def test_a_folder_that_is_not_a_report_is_refused_even_with_force(runs, tmp_path, capsys):
    mine = tmp_path / "notes"
    mine.mkdir()
    (mine / "index.md").write_text("# my own notes\n")
    (mine / "data.csv").write_text("1,2\n")
    before = _snapshot(mine)
    for force in ([], ["--force"]):
        assert main(["report", str(runs), "--out", str(mine), "--no-pictures", *force]) == 2
        err = capsys.readouterr().err.strip()
        assert err == (
            f"lightemma report: error: --out {mine} is not empty and holds no lightemma report: refusing to write over it; "
            "choose a new or empty folder"
        )
        assert _snapshot(mine) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes", "runs"]  # no hidden folder left
    # an empty folder, or a report lightemma wrote, is fine without --force
    (tmp_path / "empty").mkdir()
    assert main(["report", str(runs), "--out", str(tmp_path / "empty"), "--no-pictures"]) == 0
    assert main(["report", str(runs), "--out", str(tmp_path / "empty"), "--no-pictures"]) == 0
    (tmp_path / "afile").write_text("x")
    assert main(["report", str(runs), "--out", str(tmp_path / "afile"), "--no-pictures"]) == 2
    assert "is a file, not a folder" in capsys.readouterr().err


def _png_header_only(path, width, height):
    """A PNG that claims ``width`` × ``height`` pixels (a decompression bomb's header) with almost no data."""

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    path.write_bytes(
        b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\x00" * 64)) + chunk(b"IEND", b"")
    )


@pytest.mark.parametrize("size", [(60000, 60000), (8000, 6000)])  # over PIL's own bomb limit; over lightemma's cap only
def test_a_decompression_bomb_image_is_skipped_not_fatal(tmp_path, size):
    import numpy as np

    import lightemma
    from lightemma.backends.baseline import baseline_actions
    from lightemma.evaluation.synthetic import make_record
    from lightemma.report.figures.frame_view import load_image
    from lightemma.runs.store import RunWriter, create_run_dir
    from lightemma.synth import write_dataset

    bomb = tmp_path / "bomb.png"
    _png_header_only(bomb, *size)
    assert load_image(bomb) is None
    root = write_dataset(tmp_path / "data", scenes=2, keyframes=15, image_size=(160, 90), sweeps=False)
    frames = lightemma.load_frames(root, "v1.0-mini", split="all")
    for frame in frames:  # every camera image of the dataset is a bomb now
        bomb_bytes = bomb.read_bytes()
        open(frame.image_path, "wb").write(bomb_bytes)
    run_dir = create_run_dir(
        tmp_path / "runs", "baseline:cv", {"model": "baseline:cv", "dataset": frames.describe(), "finished_at": "t"}
    )
    with RunWriter(run_dir) as w:
        for frame in frames:
            actions = baseline_actions("cv", frame)
            w.append(
                make_record(
                    frame.frame_id,
                    frame.gt_positions,
                    lightemma.integrate(actions),
                    actions=actions,
                    history_actions=frame.history_actions,
                )
            )
    index = write_report([run_dir], tmp_path / "rep", top=1, convention="lightemma", case_tags=(), with_paper=False)
    assert index.is_file() and (tmp_path / "rep" / "index.html").is_file()
    assert not (tmp_path / "rep" / "html" / "images").exists() or not list(
        (tmp_path / "rep" / "html" / "images").iterdir()
    )
    assert np.isfinite(np.asarray(frames[0].gt_positions)).all()


@pytest.mark.parametrize("shape", ["run", "model_folder", "runs", "parent", "inside_run", "inside_runs"])
def test_an_out_that_is_holds_or_lies_in_an_input_is_refused_even_with_force(
    runs, tmp_path, monkeypatch, capsys, shape
):
    from lightemma.runs.store import find_run_dirs

    run = find_run_dirs(runs)[0]  # runs/<model>/<run id>
    out = {
        "run": run,
        "model_folder": run.parent,
        "runs": runs,
        "parent": tmp_path,
        "inside_run": run / "rep",
        "inside_runs": runs / "rep",
    }[shape]
    before = _snapshot(tmp_path)
    assert main(["report", str(runs), "--out", str(out), "--no-pictures", "--force"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"--out {out} " in err and "--force does not override this" in err
    relation = {
        "run": "is the input run directory",
        "model_folder": "contains the input run directory",
        "runs": "is the runs folder",
        "parent": "contains the",
        "inside_run": "lies inside the input run directory",
        "inside_runs": "lies inside the runs folder",
    }[shape]
    assert relation in err
    assert _snapshot(tmp_path) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["runs"]  # no hidden folder, the runs whole
    # the same through a symlink and a relative "." (real paths are compared), and a run named alone
    link = tmp_path.parent / f"{tmp_path.name}-link"
    link.symlink_to(runs, target_is_directory=True)
    assert main(["report", str(run), "--out", str(link), "--no-pictures", "--force"]) == 2
    assert "contains the input run directory" in capsys.readouterr().err
    monkeypatch.chdir(tmp_path)
    assert main(["report", "runs", "--out", ".", "--no-pictures", "--force"]) == 2
    assert "--out . contains the input run directory" in capsys.readouterr().err
    assert _snapshot(tmp_path) == before


def test_an_out_that_is_or_holds_the_dataroot_is_refused(runs, tmp_path, capsys):
    data = tmp_path / "data"
    (data / "v1.0-mini").mkdir(parents=True)
    (data / "v1.0-mini" / "scene.json").write_text("[]")
    for out in (data, tmp_path / "data" / "rep"):
        assert main(["report", str(runs), "--out", str(out), "--dataroot", str(data), "--no-pictures", "--force"]) == 2
        assert "the dataroot" in capsys.readouterr().err
    assert (data / "v1.0-mini" / "scene.json").read_text() == "[]" and not (data / "rep").exists()
    assert (
        main(
            [
                "report",
                str(runs),
                "--out",
                str(tmp_path / "rep"),
                "--dataroot",
                str(data),
                "--version",
                "v9",
                "--no-pictures",
            ]
        )
        == 2
    )
    assert (
        capsys.readouterr().err.strip() == f"lightemma report: error: --version v9: --dataroot {data} has no folder v9"
    )


def test_files_added_to_a_report_are_not_replaced_without_force(runs, tmp_path, capsys):
    import json

    out = tmp_path / "rep2"
    assert main(["report", str(runs), "--out", str(out), "--no-pictures", "--no-paper", "--top", "0"]) == 0
    marker = json.loads((out / ".lightemma-report").read_text())
    assert (
        "index.md" in marker["files"] and "index.html" in marker["files"] and ".lightemma-report" not in marker["files"]
    )
    assert sorted(marker["files"]) == sorted(
        p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file() and p.name != ".lightemma-report"
    )
    assert (
        main(["report", str(runs), "--out", str(out), "--no-pictures", "--top", "0"]) == 0
    )  # its own files only: replaced
    (out / "notes.txt").write_text("mine")
    (out / "figures" / "myfig.png").write_bytes(b"png")
    before = _snapshot(out)
    capsys.readouterr()
    assert main(["report", str(runs), "--out", str(out), "--no-pictures", "--top", "0"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (
        f"lightemma report: error: --out {out} holds 2 file(s) its report did not write (figures/myfig.png, notes.txt): "
        "refusing to replace it (--force replaces only the report's own files and keeps these)"
    )
    assert _snapshot(out) == before
    # --force replaces the report's own files and keeps the others, byte for byte; they stay not the report's
    (out / "index.md").write_text("stale")
    assert main(["report", str(runs), "--out", str(out), "--no-pictures", "--top", "0", "--force"]) == 0
    assert (out / "notes.txt").read_text() == "mine" and (out / "figures" / "myfig.png").read_bytes() == b"png"
    assert (out / "index.md").read_text().startswith("# lightemma report")
    assert "notes.txt" not in json.loads((out / ".lightemma-report").read_text())["files"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rep2", "runs"]  # the old report gone, nothing hidden left
    assert main(["report", str(runs), "--out", str(out), "--no-pictures", "--top", "0"]) == 2
    assert "holds 2 file(s) its report did not write" in capsys.readouterr().err
    # a file of the user's that the new report would write over is not replaced, --force or not
    (out / "tables" / "history_bias.md").unlink()
    (out / ".lightemma-report").write_text(
        json.dumps({"files": [f for f in marker["files"] if f != "tables/history_bias.md"]})
    )
    (out / "tables" / "history_bias.md").write_text("my own table")
    mine = _snapshot(out)
    assert main(["report", str(runs), "--out", str(out), "--no-pictures", "--top", "0", "--force"]) == 2
    assert (
        "--force cannot keep tables/history_bias.md: the new report writes a file of that name"
        in capsys.readouterr().err
    )
    assert _snapshot(out) == mine and sorted(p.name for p in tmp_path.iterdir()) == ["rep2", "runs"]
    # a report whose marker has no file list (an older lightemma's) cannot be told apart from added files: refused, --force too
    (out / "notes.txt").unlink()
    (out / "figures" / "myfig.png").unlink()
    (out / ".lightemma-report").write_text('{"written_by": "lightemma report"}\n')
    for force in ([], ["--force"]):
        assert main(["report", str(runs), "--out", str(out), "--no-pictures", "--top", "0", *force]) == 2
        err = capsys.readouterr().err
        assert (
            "without the list of its files" in err
            and "delete it yourself or choose another folder" in err
            and "--force" not in err
        )
    assert (out / "tables" / "history_bias.md").read_text() == "my own table"


def test_the_dataroot_a_run_records_is_never_replaced_even_with_force(tmp_path, capsys):
    """Issue 32.6: `report RUNS --out <the runs' own dataroot> --force` deleted the dataset."""
    data = tmp_path / "ds" / "data"
    (data / "v1.0-mini").mkdir(parents=True)
    (data / "v1.0-mini" / "scene.json").write_text("[]")
    (data / "samples").mkdir()
    (data / "samples" / "a.jpg").write_bytes(b"jpg")
    runs = tmp_path / "runs"
    write_synthetic_run(
        runs, "baseline:cv", 20, seed=2, manifest={"dataset": {"dataroot": str(data), "version": "v1.0-mini"}}
    )
    # recorded only in the run's request (config.dataset), as a resume reads it
    write_synthetic_run(
        runs, "baseline:constant", 20, seed=3, manifest={"config": {"dataset": {"dataroot": str(tmp_path / "other")}}}
    )
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "keep.json").write_text("{}")
    before = _snapshot(tmp_path)
    for out, relation in (
        (data, "is the dataroot"),
        (tmp_path / "ds", "contains the dataroot"),
        (tmp_path / "other", "is the dataroot"),
    ):
        assert main(["report", str(runs), "--out", str(out), "--no-pictures", "--force"]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and f"--out {out} {relation} " in err and "recorded by the run" in err, err
        assert "--force does not override this" in err and "--force replaces" not in err
        assert _snapshot(tmp_path) == before
    # a report beside the dataset, or inside it, replaces nothing of it and is written
    assert main(["report", str(runs), "--out", str(tmp_path / "rep"), "--no-pictures", "--top", "0"]) == 0
    assert main(["report", str(runs), "--out", str(data / "rep"), "--no-pictures", "--top", "0"]) == 0
    assert (data / "v1.0-mini" / "scene.json").read_text() == "[]" and (
        data / "samples" / "a.jpg"
    ).read_bytes() == b"jpg"


def test_a_folder_holding_a_run_is_never_replaced(runs, tmp_path, capsys):
    out = tmp_path / "rep"
    assert main(["report", str(runs), "--out", str(out), "--no-pictures", "--top", "0"]) == 0
    write_synthetic_run(out / "parked", "baseline:cv", 10, seed=4)  # a run parked in the report, not one of the inputs
    before = _snapshot(out)
    assert main(["report", str(runs), "--out", str(out), "--no-pictures", "--top", "0", "--force"]) == 2
    err = capsys.readouterr().err.strip()
    assert (
        err.startswith(f"lightemma report: error: --out {out} holds the lightemma run {out / 'parked'}")
        and "--force replaces" not in err
    )
    assert _snapshot(out) == before


@pytest.mark.slow
def test_a_report_killed_between_its_renames_is_put_back(runs, tmp_path):
    out = tmp_path / "rep"
    assert main(["report", str(runs), "--out", str(out), "--no-pictures", "--top", "0"]) == 0
    (out / "notes.txt").write_text("mine")
    before = _snapshot(out)
    dead = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"], check=True, capture_output=True, text=True
    ).stdout.strip()
    os.rename(out, tmp_path / f".rep.old-{dead}")  # what a report killed after moving the old one aside leaves
    assert (
        main(["report", str(runs), "--out", str(out), "--no-pictures", "--top", "0"]) == 2
    )  # the old one is back, with notes.txt
    assert _snapshot(out) == before and not list(tmp_path.glob(".rep.*"))
