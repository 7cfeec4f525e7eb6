"""Every "Frames" column says what it counts, and the counts add up (issue 32.11).

Table II's "Frames" are Table I's (the frames accounted); Scored + Failed + Implausible + API errors (+ "Other
unscored" where a run has frames without usable truth) are exactly those. The scenario table never puts one
model's count beside another model's value.
"""

from __future__ import annotations

import json
import os

os.environ.setdefault("MPLBACKEND", "Agg")

import numpy as np

from lightemma.evaluation import evaluate_runs
from lightemma.evaluation.synthetic import make_record, write_synthetic_run
from lightemma.report.evaluation_tables import evaluation_tables
from lightemma.report.tables import to_markdown


def _table(markdown: str) -> list[dict[str, str]]:
    lines = [line for line in markdown.splitlines() if line.startswith("|")]
    header = [c.strip() for c in lines[0].strip("|").split("|")]
    return [dict(zip(header, [c.strip() for c in line.strip("|").split("|")])) for line in lines[2:]]


def test_table_one_and_two_count_the_same_frames_and_the_outcomes_add_up(tmp_path):
    runs = tmp_path / "runs"
    write_synthetic_run(runs, "openai/gpt-4o", 208, seed=1, fail_rate=0.05)
    run = write_synthetic_run(runs, "baseline:cv", 208, seed=2, fail_rate=0.0)
    with open(run / "frames.jsonl", "a") as fh:  # one frame without usable ground truth: neither scored nor failed
        fh.write(json.dumps(make_record("scene-0100/7", np.full((6, 2), np.nan), np.zeros((6, 2)))) + "\n")
    evaluation = evaluate_runs([runs])
    tables = {t.name: t for t in evaluation_tables(evaluation)}
    efficiency = {r["Model"]: r for r in _table(to_markdown(tables["efficiency"]))}
    accuracy = {r["Model"]: r for r in _table(to_markdown(tables["accuracy_lightemma"]))}
    gpt, cv = accuracy["GPT-4o"], accuracy["baseline:cv"]
    assert int(gpt["Failed"]) > 0  # the case of the issue: some frames failed
    assert gpt["Frames"] == efficiency["GPT-4o"]["Frames"] == "208"
    assert (
        int(gpt["Scored"])
        + int(gpt["Failed"])
        + int(gpt["Implausible"])
        + int(gpt["API errors"])
        + int(gpt["Other unscored"])
        == 208
    )
    assert gpt["Other unscored"] == "0"
    assert (
        cv["Frames"] == efficiency["baseline:cv"]["Frames"] == "209"
        and cv["Other unscored"] == "1"
        and cv["Scored"] == "208"
    )
    assert any(n.startswith("Other unscored:") for n in tables["accuracy_lightemma"].notes)
    # runs whose outcomes add up without it: no such column
    clean = evaluate_runs([next(runs.glob("openai*"))])
    assert "Other unscored" not in to_markdown(
        next(t for t in evaluation_tables(clean) if t.name == "accuracy_lightemma")
    )


def test_the_scenario_table_never_shows_one_models_count_beside_anothers_values():
    from lightemma.report.writer import _scenario_table

    rows = [
        {"tag": "braking", "frames": 12, "A frames": 12, "B frames": 12, "A": {"ade_avg": 1.0}, "B": {"ade_avg": 2.0}},
        {"tag": "collides", "frames": 0, "A frames": 0, "B frames": 3, "A": None, "B": {"ade_avg": 4.5}},
    ]
    text = to_markdown(_scenario_table(rows, ["A", "B"], {}))
    table = {r["Tag"]: r for r in _table(text)}
    assert table["braking"] == {"Tag": "braking", "Frames": "12", "A": "1.00", "B": "2.00"}
    assert table["collides"] == {"Tag": "collides", "Frames": "0–3", "A": "-", "B": "4.50 (n 3)"}
    assert "each model's own count is in its cell" in text
