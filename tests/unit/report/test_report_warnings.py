"""Issue 32.12 and 32.14: repeated warnings summarised (count and first examples) on stderr and in the report, an n/a
reason said once per table, each Holm family named, and --keep-implausible's no-op said."""

from __future__ import annotations

import os
import re

os.environ.setdefault("MPLBACKEND", "Agg")

from lightemma.cli import main
from lightemma.evaluation.synthetic import write_synthetic_run
from lightemma.report import write_report
from lightemma.report.tables import Column, Table, fixed, to_csv, to_latex, to_markdown
from lightemma.report.writer import WARNINGS_FILE, summarise_warnings


def test_repeated_warnings_are_counted_with_their_first_examples():
    tokens = [f"{k:032x}" for k in range(40)]
    warnings = [
        f"GPT-4o: 1 frame(s) have no off-road value (n/a): no pose for sample {t} (e.g. scene-0001/{t})" for t in tokens
    ]
    warnings += [
        f"Claude: 1 frame(s) have no off-road value (n/a): no pose for sample {t} (e.g. scene-0002/{t})"
        for t in tokens[:2]
    ]
    warnings += ["left out /runs/a: no scored frame", "left out /runs/a: no scored frame"]  # the same text twice: once
    summary = summarise_warnings(warnings, names=["GPT-4o", "Claude"])
    assert summary[0] == (f"42 warnings like: {warnings[0]}", warnings[1:3])
    assert summary[1:] == [("left out /runs/a: no scored frame", [])]
    few = summarise_warnings(warnings[:3])
    assert few == [(w, []) for w in warnings[:3]]  # three of a kind are each said


def test_a_wrong_dataroot_gives_a_few_lines_on_stderr_and_every_warning_in_a_file(synth_root, tmp_path, capsys):
    runs = tmp_path / "runs"
    write_synthetic_run(runs, "openai/gpt-4o", 30, seed=1, noise=0.3)
    write_synthetic_run(runs, "baseline:cv", 30, seed=2, noise=1.0)
    out = tmp_path / "rep"
    write_report(
        [runs],
        out,
        top=0,
        case_tags=(),
        pictures=False,
        with_paper=False,
        pairwise=False,
        dataroot=str(synth_root),
        version="v1.0-mini",
    )
    err = capsys.readouterr().err
    every = (out / WARNINGS_FILE).read_text().splitlines()
    assert len(every) >= 100  # per frame and model: the frames are not in that dataset
    lines = [line for line in err.splitlines() if line.startswith("lightemma report:")]
    assert 0 < len(lines) <= 30, err
    counted = [int(m.group(1)) for m in re.finditer(r"lightemma report: warning: (\d+) warnings like: ", err)]
    singles = len(re.findall(r"lightemma report: warning: (?!\d+ warnings like: )", err))
    assert sum(counted) + singles == len(every)  # every warning counted once
    index = (out / "index.md").read_text()
    assert f"[{WARNINGS_FILE}]({WARNINGS_FILE})" in index and index.count("- e.g. also: ") <= 2 * len(counted)
    html = (out / "index.html").read_text()
    assert "warnings like: " in html


def test_the_reports_warnings_reach_stderr(tmp_path, capsys):
    """A warning the report itself makes (an empty run left out) is printed, not only written to index.md."""
    runs = tmp_path / "runs"
    write_synthetic_run(runs, "openai/gpt-4o", 12, seed=1, noise=0.3)
    empty = write_synthetic_run(runs, "baseline:cv", 12, seed=2, noise=1.0)
    (empty / "frames.jsonl").write_text("")
    for side in empty.glob("frames.columns*"):
        side.unlink()
    write_report(
        [runs], tmp_path / "rep", top=0, case_tags=(), pictures=False, with_paper=False, pairwise=False, safety=False
    )
    err = capsys.readouterr().err
    assert f"lightemma report: warning: left out {empty}" in err


def test_an_na_reason_is_said_once_per_table():
    reason = "no dataroot (pass --dataroot and --version)"
    cols = [Column("model", "Model"), *(Column(f"m{k}", f"M{k}", fixed(2), na="why") for k in range(11))]
    rows = [{"model": name, "why": reason, **{f"m{k}": None for k in range(11)}} for name in ("A", "B")]
    table = Table("Safety", cols, rows)
    md = to_markdown(table)
    assert md.count(reason) == 1 and md.count(" n/a |") == 22 and f"Every n/a in this table: n/a ({reason})." in md
    assert to_latex(table).count(reason) == 1
    assert to_csv(table).count(reason) == 22  # a CSV has no notes: each cell keeps its reason
    rows[1]["why"] = "no annotations"
    md = to_markdown(Table("Safety", cols, rows))
    assert md.count("n/a [1] |") == 11 and md.count("n/a [2] |") == 11
    assert (
        f"Every n/a [1] in this table: n/a ({reason})." in md
        and "Every n/a [2] in this table: n/a (no annotations)." in md
    )


def test_each_table_names_its_holm_family(tmp_path):
    from lightemma.evaluation import evaluate_runs
    from lightemma.evaluation.stats import Resampling
    from lightemma.report.evaluation_tables import evaluation_tables

    runs = tmp_path / "runs"
    for k, model in enumerate(("openai/gpt-4o", "gemini/gemini-2.0-flash", "baseline:cv")):
        write_synthetic_run(runs, model, 20, seed=k, noise=0.3 + k)
    ev = evaluate_runs([runs], resampling=Resampling(n_resamples=50), pairwise=True, safety=False, planning=False)
    tables = [t for t in evaluation_tables(ev) if any(c.key.endswith("p_holm") for c in t.columns)]
    assert tables
    for t in tables:
        notes = " ".join(t.notes)
        assert "Holm family: " in notes and "its own family" in notes, (t.name, notes)


def test_keep_implausible_says_when_it_changes_nothing(tmp_path, capsys):
    runs = tmp_path / "runs"
    write_synthetic_run(runs, "openai/gpt-4o", 12, seed=1, noise=0.3)
    args = ["evaluate", str(runs), "--keep-implausible", "--resamples", "0", "--no-planning", "--no-safety"]
    assert main(args) == 0
    err = capsys.readouterr().err
    assert "note: --keep-implausible changes nothing for GPT-4o" in err
    assert main([*args, "--parse", "paper"]) == 0
    assert "--keep-implausible changes nothing" not in capsys.readouterr().err
    assert main(args[:2] + args[3:]) == 0
    assert "--keep-implausible" not in capsys.readouterr().err
