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


def test_a_killed_report_leaves_the_old_one_whole_and_its_leftovers_go_next_time(runs, tmp_path):
    out = tmp_path / "rep"
    assert main(["report", str(runs), "--out", str(out), "--no-pictures", "--no-paper", "--top", "0"]) == 0
    before = _snapshot(out)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    proc = subprocess.Popen([sys.executable, "-m", "lightemma", "report", str(runs), "--out", str(out), "--top", "3"], env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
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


def test_a_folder_that_is_not_a_report_is_refused_without_force(runs, tmp_path, capsys):
    mine = tmp_path / "notes"
    mine.mkdir()
    (mine / "index.md").write_text("# my own notes\n")
    (mine / "data.csv").write_text("1,2\n")
    before = _snapshot(mine)
    assert main(["report", str(runs), "--out", str(mine), "--no-pictures"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"lightemma report: error: --out {mine} is not empty and holds no lightemma report: refusing to overwrite it (--force replaces it)"
    assert _snapshot(mine) == before
    assert main(["report", str(runs), "--out", str(mine), "--no-pictures", "--force"]) == 0
    assert (mine / "index.md").read_text().startswith("# lightemma report") and not (mine / "data.csv").exists()
    # an empty folder, or a report lightemma wrote, is fine without --force
    (tmp_path / "empty").mkdir()
    assert main(["report", str(runs), "--out", str(tmp_path / "empty"), "--no-pictures"]) == 0
    assert main(["report", str(runs), "--out", str(mine), "--no-pictures"]) == 0
    (tmp_path / "afile").write_text("x")
    assert main(["report", str(runs), "--out", str(tmp_path / "afile"), "--no-pictures"]) == 2
    assert "is a file, not a folder" in capsys.readouterr().err


def _png_header_only(path, width, height):
    """A PNG that claims ``width`` × ``height`` pixels (a decompression bomb's header) with almost no data."""
    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\x00" * 64)) + chunk(b"IEND", b""))


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
    run_dir = create_run_dir(tmp_path / "runs", "baseline:cv", {"model": "baseline:cv", "dataset": frames.describe(), "finished_at": "t"})
    with RunWriter(run_dir) as w:
        for frame in frames:
            actions = baseline_actions("cv", frame)
            w.append(make_record(frame.frame_id, frame.gt_positions, lightemma.integrate(actions), actions=actions, history_actions=frame.history_actions))
    index = write_report([run_dir], tmp_path / "rep", top=1, convention="lightemma", case_tags=(), with_paper=False)
    assert index.is_file() and (tmp_path / "rep" / "index.html").is_file()
    assert not (tmp_path / "rep" / "html" / "images").exists() or not list((tmp_path / "rep" / "html" / "images").iterdir())
    assert np.isfinite(np.asarray(frames[0].gt_positions)).all()
