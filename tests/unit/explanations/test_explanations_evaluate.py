"""The explanation audit in ``lightemma evaluate`` (python/lightemma/evaluation/intent_audit.py,
docs/definitions.md#explanation-audit): a loopback model whose stated intent contradicts its plan at known frames,
its no-image run, and a baseline without stage texts."""

from __future__ import annotations

import itertools
import json
import re
import threading

import numpy as np
import pytest

from lightemma.cli import main
from lightemma.explanations import intent_consistency, read_intents
from lightemma.nuscenes import load_frames
from lightemma.pipeline import run
from lightemma.runs.store import FRAMES_FILE
from tests.support.fake_openai import FakeOpenAIServer, Reply

LIE = "The ego vehicle has been driving in its lane. It should come to a complete stop."
HONEST = "The ego vehicle has been driving in its lane. It should maintain its current speed and keep its lane."
KEYS = ("consistent", "contradicts", "intent_unknown", "intent_accuracy")


def _model(lie_every: int | None):
    counter, lock = itertools.count(), threading.Lock()

    def model(req):
        if req.stage == "scene":
            return Reply("A quiet street with parked cars.")
        if req.stage == "intent":
            with lock:
                k = next(counter)
            return Reply(LIE if lie_every and k % lie_every == 0 else HONEST)
        history = req.text.split("Driving intent", 1)[0]
        v0 = float(re.findall(r"\(\s*(-?[\d.]+(?:e-?\d+)?)\s*,", history)[-1])
        v = v0 + 3.0 if "complete stop" in req.text else v0  # the liar says stop and speeds up
        return Reply("[" + ", ".join(f"({v:.3f}, 0.0)" for _ in range(6)) + "]")

    return model


def _records(run_dir):
    lines = (run_dir / FRAMES_FILE).read_text(encoding="utf-8").splitlines()
    return {r["frame_id"]: r for r in map(json.loads, lines)}


@pytest.fixture(scope="module")
def runs(tmp_path_factory, synth_root):
    out = tmp_path_factory.mktemp("explain") / "runs"
    dirs = {}
    for inputs, lie_every in (("full", 3), ("no-image", None)):
        with FakeOpenAIServer(_model(lie_every)) as server:
            dirs[inputs] = run(
                "openai/gpt-4o",
                api_base=server.url,
                dataroot=synth_root,
                version="v1.0-mini",
                output=out,
                backoff_base=0.01,
                backoff_cap=0.05,
                timeout=10.0,
                progress=False,
                inputs=inputs,
            ).run_dir
    assert (
        main(
            [
                "run",
                "--model",
                "baseline:cv",
                "--dataroot",
                str(synth_root),
                "--version",
                "v1.0-mini",
                "--split",
                "all",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    (dirs["baseline"],) = (out / "baseline-cv").iterdir()
    return out, dirs


def _evaluate(capsys, *args):
    capsys.readouterr()
    assert main(["evaluate", *map(str, args), "--resamples", "200"]) == 0
    return capsys.readouterr().out


def _table(document, name):
    (table,) = [t for t in document["tables"] if t["name"] == name]
    return table


def test_json_rates_intervals_and_na_for_the_baseline(runs, capsys, synth_root):
    out, dirs = runs
    document = json.loads(_evaluate(capsys, out, "--format", "json"))
    table = _table(document, "explanations")
    rows = {r["model"]: r for r in table["rows"]}
    full, baseline = rows["openai/gpt-4o"], rows["Baseline (constant velocity)"]

    records = _records(dirs["full"])
    lied = sorted(fid for fid, r in records.items() if r["intent_text"] == LIE)
    n = len(records)
    assert 0 < len(lied) < n == full["explanation_frames"] == 12
    assert full["contradicts"] == pytest.approx(len(lied) / n)
    assert full["consistent"] + full["contradicts"] + full["intent_unknown"] == pytest.approx(1.0)
    for key in KEYS:
        assert full[f"{key}_na"] is None and 0.0 <= full[key] <= 1.0
        low, high = full[f"{key}_ci95"]
        assert low <= full[key] <= high
        assert baseline[key] is None and baseline[f"{key}_ci95"] is None
        assert baseline[f"{key}_na"].startswith("no stage-2 texts")

    # intent accuracy: the stated intent against the classes of the dataroot's ground truth, on the same frames
    fs = load_frames(synth_root, "v1.0-mini", split="all", window="full")
    index = {fid: i for i, fid in enumerate(fs.frame_ids)}
    ids = list(records)
    rows_gt = np.array([index[f] for f in ids])
    truth = intent_consistency(
        read_intents([records[f]["intent_text"] for f in ids]),
        fs.gt_actions[rows_gt],
        fs.history_actions[rows_gt],
        fs.gt_positions[rows_gt],
    )
    assert full["intent_accuracy"] == pytest.approx(float(np.mean(truth.verdict == "consistent")))

    # every column has its descriptor; the audit's own JSON section
    described = document["columns"]["explanations"]
    assert {k for r in table["rows"] for k in r} == set(described)
    assert all(described[k] is not None for k in described)
    assert described["intent_accuracy"]["range"] == [0.0, 1.0]
    (change,) = _table(document, "intent_ablations")["rows"]
    assert change["intent_changed"] == pytest.approx(len(lied) / n)
    assert all(d is not None for d in document["columns"]["intent_ablations"].values())


def test_the_stated_intent_under_the_ablation(runs):
    from lightemma.evaluation import evaluate_runs
    from lightemma.evaluation.stats import Resampling

    out, dirs = runs
    evaluation = evaluate_runs([out], resampling=Resampling(n_resamples=200), safety=False, planning=False)
    rows = {m.label: m.explanations for m in evaluation.models}
    assert rows["openai/gpt-4o [no-image]"]["contradicts"] == 0.0
    records = _records(dirs["full"])
    lied = [fid for fid, r in records.items() if r["intent_text"] == LIE]
    n = len(records)
    # the no-image run's stated intent changed exactly where the full run lied
    (change,) = evaluation.explanations.ablations
    assert (change["model"], change["ablation"]) == ("openai/gpt-4o", "no-image")
    assert change["ablated"] == "openai/gpt-4o [no-image]"
    assert change["frames"] == n and change["intent_changed"] == pytest.approx(len(lied) / n)
    assert change["intent_changed_na"] is None
    low, high = change["intent_changed_ci95"]
    assert low <= change["intent_changed"] <= high
    section = evaluation.to_dict()["explanations"]
    assert section["rules"] == "intent@lightemma/1" and section["ablations"] == [change]
    assert section["rows"]["openai/gpt-4o"]["contradicts"] == pytest.approx(len(lied) / n)


def test_markdown_table_and_the_switch(runs, capsys):
    out, _ = runs
    text = _evaluate(capsys, out)
    assert "### Explanations" in text and "Intent accuracy [95% CI]" in text
    section = text.split("### Explanations", 1)[1].split("\n### ", 1)[0]
    line = next(x for x in section.splitlines() if x.startswith("| Baseline (constant velocity) |"))
    assert line.count("n/a") == 6 and "0.000" not in line  # 4 intent columns, 2 described-objects columns
    assert "n/a (no stage-2 texts" in section
    assert "### Stated intent without the image" in text
    assert "### Explanations" not in _evaluate(capsys, out, "--no-explanations")


def test_another_datasets_ground_truth_is_na_with_the_reason(runs, capsys, tmp_path):
    import shutil

    _, dirs = runs
    copy = tmp_path / "copy"
    shutil.copytree(dirs["full"], copy)
    records = list(_records(copy).values())
    records[0]["gt_positions"][5][0] += 0.5
    (copy / FRAMES_FILE).write_text("".join(json.dumps(r) + "\n" for r in records), encoding="utf-8")
    document = json.loads(_evaluate(capsys, copy, "--format", "json"))
    (row,) = _table(document, "explanations")["rows"]
    assert row["intent_accuracy"] is None and "differs from" in row["intent_accuracy_na"]
    assert row["contradicts"] is not None  # the plan check needs no dataset


def test_says_stop_drives_on_tags_the_lies(runs):
    from lightemma.evaluation import evaluate_runs
    from lightemma.evaluation.intent_audit import says_stop_drives_on
    from lightemma.evaluation.loading import load_run
    from lightemma.evaluation.scenarios import per_tag_metrics
    from lightemma.evaluation.stats import Resampling

    _, dirs = runs
    evaluation = evaluate_runs(
        [dirs["full"], dirs["baseline"]], resampling=Resampling(n_resamples=0), safety=False, planning=False
    )
    audit = evaluation.explanations.runs["openai/gpt-4o"]
    lied = sorted(fid for fid, r in _records(dirs["full"]).items() if r["intent_text"] == LIE)
    assert sorted(np.asarray(audit.frame_ids)[says_stop_drives_on(audit)].tolist()) == lied
    loaded = [load_run(d, details=True) for d in (dirs["full"], dirs["baseline"])]
    rows = {r["tag"]: r for r in per_tag_metrics(loaded, explanations=evaluation.explanations)}
    tag = rows["says-stop-drives-on"]
    assert tag["openai/gpt-4o frames"] == len(lied) and tag["Baseline (constant velocity) frames"] == 0
    assert "says-stop-drives-on" not in {r["tag"] for r in per_tag_metrics(loaded)}


def test_report_has_the_figure_and_the_tag(runs, tmp_path, capsys):
    _, dirs = runs
    report = tmp_path / "report"
    assert main(["report", str(dirs["full"]), str(dirs["baseline"]), "--out", str(report)]) == 0
    index = (report / "index.md").read_text(encoding="utf-8")
    assert "## Explanations" in index and "says-stop-drives-on" in index
    assert (report / "figures" / "explanations.png").stat().st_size > 0
