"""What `evaluate` and `report` read from a folder of runs (issue 32.7, 32.14): a corrupt manifest or a linked run is
left out with a warning naming it, never silently and never blocking the others; `-o` writes only into a folder
that exists."""

from __future__ import annotations

import os

os.environ.setdefault("MPLBACKEND", "Agg")

import pytest

from lightemma.cli import main
from lightemma.evaluation import evaluate_runs
from lightemma.evaluation.synthetic import write_synthetic_run


@pytest.fixture()
def runs(tmp_path):
    runs = tmp_path / "runs"
    write_synthetic_run(runs, "openai/gpt-4o", 20, seed=1, noise=0.4)
    write_synthetic_run(runs, "baseline:cv", 20, seed=2, noise=1.2)
    return runs


def test_a_corrupt_manifest_is_left_out_with_a_warning(runs, tmp_path, capsys):
    broken = write_synthetic_run(runs, "gemini/gemini-2.0-flash", 20, seed=3)
    (broken / "manifest.json").write_text('{"format": "lightemma-run/1", "model": ')  # cut off mid-write
    evaluation = evaluate_runs([runs])
    assert sorted(m.label for m in evaluation.models) == ["GPT-4o", "baseline:cv"]
    assert any(w.startswith(f"left out {broken}: ") and "is unreadable" in w for w in evaluation.warnings), (
        evaluation.warnings
    )
    assert main(["evaluate", str(runs)]) == 0
    captured = capsys.readouterr()
    assert f"lightemma evaluate: warning: left out {broken}: " in captured.err and "| GPT-4o |" in captured.out
    assert main(["report", str(runs), "--out", str(tmp_path / "rep"), "--no-pictures", "--top", "0", "--no-paper"]) == 0
    assert f"left out {broken}: " in (tmp_path / "rep" / "index.md").read_text()
    assert f"lightemma report: warning: left out {broken}: " in capsys.readouterr().err  # on stderr too
    # named by itself it is an error, in one line
    assert main(["evaluate", str(broken)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "is unreadable" in err
    # a folder whose only run is corrupt: an error saying why
    alone = tmp_path / "alone"
    alone.mkdir()
    os.rename(broken, alone / "run")
    assert main(["evaluate", str(alone)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "no readable lightemma run" in err and "is unreadable" in err


def test_a_linked_run_is_named_not_silently_left_out(runs, tmp_path, capsys):
    elsewhere = tmp_path / "elsewhere"
    linked = write_synthetic_run(elsewhere, "gemini/gemini-2.0-flash", 20, seed=3)
    (runs / "shared").symlink_to(elsewhere, target_is_directory=True)
    evaluation = evaluate_runs([runs])
    assert len(evaluation.models) == 2
    (warning,) = [w for w in evaluation.warnings if w.startswith("left out")]
    assert warning == (
        f"left out {runs / 'shared'}: a symbolic link to {elsewhere} holding 1 run(s), not followed; "
        "give it by its own path to include it"
    )
    assert main(["report", str(runs), "--out", str(tmp_path / "rep"), "--no-pictures", "--top", "0", "--no-paper"]) == 0
    assert f"left out {runs / 'shared'}: a symbolic link" in (tmp_path / "rep" / "index.md").read_text()
    # given by its own path it is read
    assert len(evaluate_runs([runs, runs / "shared"]).models) == 3
    assert linked.is_dir()


def test_evaluate_output_needs_an_existing_folder(runs, tmp_path, capsys):
    target = tmp_path / "no" / "such" / "tables.md"
    assert main(["evaluate", str(runs), "-o", str(target)]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"lightemma evaluate: error: -o {target}: the folder {target.parent} does not exist (create it first)"
    assert not (tmp_path / "no").exists()
    assert main(["evaluate", str(runs), "-o", str(tmp_path / "tables.md")]) == 0
    assert (tmp_path / "tables.md").read_text().startswith("### ")
