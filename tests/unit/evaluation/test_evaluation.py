"""`lightemma evaluate`: numbers against an independent NumPy computation from frames.jsonl,
--common, FE/efficiency accounting, table layouts, and bad input handled in one line."""

from __future__ import annotations

import csv
import io
import json
import re
from pathlib import Path

import numpy as np
import pytest

from lightemma.cli import main
from lightemma.errors import RunStoreError, UserError
from lightemma.evaluation import columns, evaluate_runs, load_run
from lightemma.evaluation.synthetic import make_record, write_synthetic_run
from lightemma.report.evaluation_tables import evaluation_tables
from lightemma.report.tables import render
from lightemma.runs.store import FRAMES_FILE, RunWriter, create_run_dir, update_manifest

SLICES = {
    "lightemma": ([0, 1], [2, 3], [4, 5]),
    "stp3": ([0, 1], [0, 1, 2, 3], [0, 1, 2, 3, 4, 5]),
    "uniad": ([1], [3], [5]),
}


def numpy_reference(run_dir: Path, convention: str, only: set[str] | None = None) -> dict[str, float]:
    """Metrics straight from frames.jsonl with NumPy (last record per frame wins)."""
    records: dict[str, dict] = {}
    for line in (run_dir / FRAMES_FILE).read_text().splitlines():
        try:
            rec = json.loads(line)
        except json.JSONDecodeError:
            continue
        records[rec["frame_id"]] = rec
    pred, gt, first = [], [], []
    for fid, rec in records.items():
        first.append(rec["first_status"])
        if rec["status"] == "failed" or rec["trajectory"] is None or (only is not None and fid not in only):
            continue
        pred.append(rec["trajectory"])
        gt.append(rec["gt_positions"])
    err = np.sqrt(((np.array(pred) - np.array(gt)) ** 2).sum(-1))
    s1, s2, s3 = SLICES[convention]
    columns = [err[:, s].mean(1) for s in (s1, s2, s3)]
    # ADE avg: lightemma mean(e1..e6); stp3 and uniad the mean of their three columns (as those papers print "Avg.")
    avg = err.mean(1) if convention == "lightemma" else np.mean(columns, axis=0)
    return {
        "ade_1s": columns[0].mean(),
        "ade_2s": columns[1].mean(),
        "ade_3s": columns[2].mean(),
        "ade_avg": avg.mean(),
        "fde": err[:, 5].mean(),
        "miss_rate": (err.max(1) > 2.0).mean(),
        "frames": len(err),
        "fe_pct": 100 * np.mean([f != "ok" for f in first]),
        "fe_corr_pct": 100 * np.mean([f == "failed" for f in first]),
    }


@pytest.fixture(scope="module")
def two_runs(tmp_path_factory):
    out = tmp_path_factory.mktemp("runs")
    a = write_synthetic_run(out, "openai/gpt-4o", 120, seed=1, noise=0.4, fe_rate=0.2, fail_rate=0.05)
    b = write_synthetic_run(out, "baseline:cv", 100, seed=2, noise=1.2, fe_rate=0.0, fail_rate=0.0, cost_cents=None)
    return out, a, b


@pytest.mark.parametrize("convention", ["lightemma", "stp3", "uniad"])
def test_metrics_equal_numpy_reference(two_runs, convention):
    out, a, b = two_runs
    ev = evaluate_runs([out], convention=convention)
    rows = {r["model"]: r for r in ev.accuracy_rows(convention)}
    for label, run_dir in (("GPT-4o", a), ("baseline:cv", b)):
        ref = numpy_reference(run_dir, convention)
        row = rows[label]
        assert row["frames"] == ref["frames"]
        for key in ("ade_1s", "ade_2s", "ade_3s", "ade_avg", "fde", "miss_rate", "fe_pct", "fe_corr_pct"):
            assert row[key] == pytest.approx(ref[key], rel=1e-12, abs=1e-12), key


def test_common_uses_frames_valid_for_every_run(two_runs):
    out, a, b = two_runs
    ev = evaluate_runs([a, b], convention="all", common=True)
    valid = [{fid for fid, ok in zip(r.frame_ids, r.valid) if ok} for r in (load_run(a), load_run(b))]
    shared = valid[0] & valid[1]
    assert ev.n_common == len(shared) < 100
    for convention in ("lightemma", "stp3", "uniad"):
        for row, run_dir in zip(ev.accuracy_rows(convention), (a, b)):
            ref = numpy_reference(run_dir, convention, only=shared)
            assert row["frames"] == len(shared)
            assert row["ade_avg"] == pytest.approx(ref["ade_avg"], rel=1e-12)
            assert row["fde"] == pytest.approx(ref["fde"], rel=1e-12)


def test_different_frame_sets_warn_with_count(two_runs):
    out, a, b = two_runs
    ev = evaluate_runs([a, b])
    assert any("20 of 120 frames are not in every run" in w and "--common" in w for w in ev.warnings)


def test_efficiency_accounting(two_runs):
    out, a, b = two_runs
    recs = [json.loads(line) for line in (a / FRAMES_FILE).read_text().splitlines()]
    row = {r["model"]: r for r in evaluate_runs([out]).efficiency_rows()}
    gpt = row["GPT-4o"]
    assert gpt["seconds_per_frame"] == pytest.approx(np.mean([r["seconds"] for r in recs]))
    assert gpt["cost_cents_per_frame"] == pytest.approx(np.mean([r["cost_cents"] for r in recs]))
    assert gpt["input_tokens"] == pytest.approx(np.mean([r["input_tokens"] for r in recs]))
    assert gpt["output_tokens"] == pytest.approx(np.mean([r["output_tokens"] for r in recs]))
    assert gpt["run_wall_seconds"] == 600.0
    assert gpt["frames_per_second"] == pytest.approx(120 / 600.0)
    assert row["baseline:cv"]["cost_cents_per_frame"] is None  # no frame has a known cost


def test_models_ordered_by_family_and_labelled(tmp_path):
    for model in (
        "meta-llama/Llama-3.2-11B-Vision-Instruct",
        "baseline:constant",
        "gemini/gemini-2.0-flash",
        "openai/gpt-5.2",
        "openai/gpt-4o",
    ):
        write_synthetic_run(tmp_path, model, 5)
    rows = evaluate_runs([tmp_path]).accuracy_rows()
    assert [r["model"] for r in rows] == ["GPT-4o", "GPT-5.2", "Gemini-2.0-Flash", "LLaMA-3.2-11B", "baseline:constant"]
    assert [r["family"] for r in rows] == ["GPT", "GPT", "Gemini", "LLaMA", "Baseline"]


def test_every_registry_id_of_a_paper_model_is_recognised():
    from lightemma.models.catalog import PAPER_MODELS
    from lightemma.models.names import known_model

    for info in PAPER_MODELS:
        for name in (info.key, info.display_name, info.model_id):
            found = known_model(name)
            assert found is not None and found.display_name == info.display_name, name


def test_same_model_twice_is_told_apart_by_integrator(tmp_path):
    write_synthetic_run(tmp_path, "baseline:oracle", 5, manifest={"integrator": "euler"})
    write_synthetic_run(tmp_path, "baseline:oracle", 5, manifest={"integrator": {"method": "midpoint"}})
    labels = sorted(r["model"] for r in evaluate_runs([tmp_path]).accuracy_rows())
    assert labels == ["baseline:oracle", "baseline:oracle [midpoint]"]  # euler is the paper's: not named


def test_records_without_trajectory_are_integrated_from_actions(tmp_path):
    run_dir = create_run_dir(tmp_path, "x/model", {"model": "x/model", "integrator": "euler", "finished_at": "t"})
    actions = np.array([[2.0, 0.0]] * 6)
    with RunWriter(run_dir) as w:
        w.append(make_record("f1", np.zeros((6, 2)), None, actions=actions))
    row = evaluate_runs([run_dir]).accuracy_rows()[0]
    # straight at 2 m/s for 3 s: positions 1..6 m ahead; FDE 6, ADE avg 3.5
    assert row["frames"] == 1
    assert row["fde"] == pytest.approx(6.0)
    assert row["ade_avg"] == pytest.approx(3.5)


def test_corrupt_lines_truncated_tail_and_unfinished_run(tmp_path):
    run_dir = write_synthetic_run(tmp_path, "openai/gpt-4o", 10, finished=False, fail_rate=0.0)
    with open(run_dir / FRAMES_FILE, "a") as fh:
        fh.write("{not json\n")
        fh.write('{"frame_id": "x", "gt_positions": [1, 2]}\n')
        fh.write('{"frame_id": "half')
    ev = evaluate_runs([run_dir])
    text = "\n".join(ev.warnings)
    assert "1 corrupt line" in text
    assert "truncated last line" in text
    assert "1 record(s) without usable ground truth" in text
    assert "in progress" in text and "10 frame(s)" in text
    assert ev.accuracy_rows()[0]["frames"] == 10


def test_duplicate_frames_last_record_wins(tmp_path):
    run_dir = create_run_dir(tmp_path, "m", {"model": "m", "finished_at": "t"})
    gt = np.zeros((6, 2))
    with RunWriter(run_dir) as w:
        w.append(make_record("f1", gt, None, status="failed"))
        w.append(make_record("f1", gt, np.ones((6, 2)), status="ok", first_status="failed"))
    data = load_run(run_dir)
    assert data.duplicates == 1 and len(data) == 1
    row = evaluate_runs([run_dir]).accuracy_rows()[0]
    assert row["frames"] == 1 and row["fde"] == pytest.approx(np.sqrt(2))
    assert row["fe_corr_pct"] == 100.0


def test_foreign_and_missing_directories_raise_clear_errors(tmp_path):
    (tmp_path / "foreign").mkdir()
    (tmp_path / "foreign" / "manifest.json").write_text('{"format": "something-else"}')
    with pytest.raises(RunStoreError, match="not a lightemma run manifest"):
        evaluate_runs([tmp_path / "foreign"])
    (tmp_path / "empty").mkdir()
    with pytest.raises(RunStoreError, match="holds no lightemma run"):
        evaluate_runs([tmp_path / "empty"])
    with pytest.raises(UserError, match="no run directories given"):
        evaluate_runs([])


def test_common_with_nothing_shared_is_a_user_error(tmp_path):
    a = create_run_dir(tmp_path, "a", {"model": "a", "finished_at": "t"})
    b = create_run_dir(tmp_path, "b", {"model": "b", "finished_at": "t"})
    with RunWriter(a) as w:
        w.append(make_record("f1", np.zeros((6, 2)), np.zeros((6, 2))))
    with RunWriter(b) as w:
        w.append(make_record("f2", np.zeros((6, 2)), np.zeros((6, 2))))
    with pytest.raises(UserError, match="no frame is valid for every run"):
        evaluate_runs([a, b], common=True)


def test_cli_errors_are_one_line(tmp_path, capsys):
    (tmp_path / "foreign").mkdir()
    (tmp_path / "foreign" / "manifest.json").write_text("{broken")
    assert main(["evaluate", str(tmp_path / "foreign")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("lightemma evaluate: error:") and "unreadable" in err
    assert "\n" not in err and "Traceback" not in err


def test_cli_markdown_layout_with_paper(two_runs, capsys):
    out, a, b = two_runs
    assert main(["evaluate", str(a), str(b), "--with-paper", "--common"]) == 0
    text = capsys.readouterr().out
    lines = text.splitlines()
    header = next(i for i, line in enumerate(lines) if line.startswith("| Model | Frames | Scored"))
    assert lines[header] == (
        "| Model | Frames | Scored | Failed | Implausible | API errors | FE (%) | FE corr (%) | ADE 1s (m) | ADE 2s (m) | ADE 3s (m) "
        "| ADE avg (m) [95% CI] | FDE (m) [95% CI] | Miss (%) | Parse |"
    )
    body = lines[header + 2 : header + 2 + 18]
    # the run, then the paper's row of its model, then the difference; then the baseline; then the other paper rows
    assert body[0].startswith("| GPT-4o (synthetic data) | ") and body[0].endswith("| lenient |")  # synthetic records
    assert re.search(
        r"\| GPT-4o \(synthetic data\) \| \d+ \| \d+ \| \d+ \| 0 \| 0 \| [\d.]+ \| [\d.]+ \| [\d.]+ \| [\d.]+ \| [\d.]+ \| [\d.]+ \[[\d.]+, [\d.]+\] \| [\d.]+ \[[\d.]+, [\d.]+\] \|",
        body[0],
    )
    assert (
        body[1]
        == "| GPT-4o (paper) | 3908 | - | - | - | - | 7.78 | 0.08 | 0.28 | 0.92 | 2.01 | 1.07 | 2.34 | - | paper |"
    )
    assert body[2].startswith("| Δ vs paper | - | ") and body[3].startswith("| baseline:cv (synthetic data) | ")
    assert body[4].startswith("| GPT-5.0 (paper) | ") and len([b for b in body if "(paper)" in b]) == 15
    assert "| Gemini-2.5-Flash (paper) | 28.5 | 1.35† | 1968† | - | 402 | - | - | - | 3908 |" in text
    assert all(len(line.split("|")) == 17 for line in body)
    assert lines[header + 2 + 18] == ""  # the table ends after the 18 rows (3 + the baseline + 14 other paper rows)
    assert "95 % scene-level bootstrap interval (10000 resamples of scenes, seed 0)" in text


def test_csv_latex_json_formats(two_runs, capsys):
    out, a, b = two_runs
    ev = evaluate_runs([out], convention="all")
    tables = evaluation_tables(ev)
    csv_text = render(tables, "csv")
    blocks = [blk for blk in csv_text.split("\n\n") if blk.strip()]
    assert len(blocks) == 6  # efficiency + three conventions + explanations + the model's gain over the baseline
    rows = list(csv.reader(io.StringIO(blocks[1].split("\n", 1)[1])))
    assert rows[0][:3] == ["Model", "Frames", "Scored"] and len(rows) == 3
    col = rows[0].index("ADE avg (m)")
    assert rows[0][col + 1 : col + 3] == ["ADE avg (m) CI low", "ADE avg (m) CI high"]
    first = ev.accuracy_rows("lightemma")[0]
    assert float(rows[1][col]) == pytest.approx(first["ade_avg"], abs=0.005)
    assert [float(v) for v in rows[1][col + 1 : col + 3]] == pytest.approx(first["ade_avg_ci95"], abs=0.005)
    latex = render(tables, "latex")
    assert latex.count(r"\begin{tabular}") == 6 and r"FE (\%)" in latex and r"\textcent{}" in latex
    doc = json.loads(render(tables, "json", extra={"common": False}))
    assert [t["name"] for t in doc["tables"]] == [
        "efficiency",
        "accuracy_lightemma",
        "accuracy_stp3",
        "accuracy_uniad",
        "explanations",
        "baseline_gains",
    ]
    assert doc["tables"][1]["rows"][0]["ade_avg"] == ev.accuracy_rows("lightemma")[0]["ade_avg"]
    low, high = doc["tables"][1]["rows"][0]["ade_avg_ci95"]
    assert low < doc["tables"][1]["rows"][0]["ade_avg"] < high and len(doc["tables"][1]["rows"][0]["fde_ci95"]) == 2
    assert main(["evaluate", str(out), "--format", "json"]) == 0
    assert json.loads(capsys.readouterr().out)["tables"][0]["name"] == "efficiency"


def test_rows_as_columns(two_runs):
    out, a, b = two_runs
    cols = columns(evaluate_runs([out]).accuracy_rows())
    assert cols["model"] == ["GPT-4o", "baseline:cv"]
    assert len(cols["ade_avg"]) == 2 and set(cols) >= {"fe_pct", "fde", "miss_rate", "frames"}


def test_missing_manifest_keys_fall_back(tmp_path):
    run_dir = create_run_dir(tmp_path, "somebody/unknown-vlm", {"model": "somebody/unknown-vlm"})
    with RunWriter(run_dir) as w:
        w.append(make_record("f1", np.zeros((6, 2)), np.zeros((6, 2)), seconds=2.0, input_tokens=None))
    update_manifest(run_dir, backend={"gpus": 2})
    row = evaluate_runs([run_dir]).efficiency_rows()[0]
    assert row["model"] == "somebody/unknown-vlm" and row["family"] == "Other"
    assert row["gpus"] == 2 and row["input_tokens"] is None and row["run_wall_seconds"] is None


def test_manifest_in_the_run_pipelines_shape(tmp_path):
    manifest = {
        "model": "baseline:oracle",
        "display_name": "Baseline (oracle actions)",
        "model_info": {"family": "baseline", "generation": 0, "gpus": 0},
        "backend": {"backend": "baseline", "kind": "oracle"},
        "config": {"integrate_method": "midpoint", "concurrency": 4},
        "sessions": [{"wall_seconds": 10.0}, {"wall_seconds": 5.0}],
        "finished_at": "2026-01-01T00:00:15+00:00",
    }
    run_dir = create_run_dir(tmp_path, "baseline:oracle", manifest)
    with RunWriter(run_dir) as w:
        for i in range(3):
            w.append(make_record(f"f{i}", np.zeros((6, 2)), np.zeros((6, 2))))
    ev = evaluate_runs([run_dir])
    model = ev.models[0]
    assert (model.label, model.family, model.integrator) == (
        "Baseline (oracle actions) [midpoint]",
        "Baseline",
        "midpoint",
    )  # not the paper's euler
    row = ev.efficiency_rows()[0]
    assert row["run_wall_seconds"] == 15.0 and row["frames_per_second"] == pytest.approx(0.2)
    assert row["gpus"] is None and row["concurrency"] == 4


def test_interrupted_session_makes_the_run_wall_time_unknown(tmp_path):
    """A session killed or interrupted records no wall time; the last session's alone is not the run's.

    Before: Table I showed the resumed session's 5 s as the run's wall time and 3 / 5 s as its
    frames/s, although the first session also ran frames for an unknown time.
    """
    manifest = {
        "model": "baseline:cv",
        "sessions": [
            {"kind": "run", "started_at": "2026-01-01T00:00:00+00:00"},  # SIGKILLed: no wall time
            {"kind": "resume", "wall_seconds": 5.0, "frames_run": 2},
        ],
        "summary": {"wall_seconds": 5.0, "frames_run": 2},  # the last session's
        "finished_at": "2026-01-01T00:01:00+00:00",
    }
    run_dir = create_run_dir(tmp_path, "baseline:cv", manifest)
    with RunWriter(run_dir) as w:
        for i in range(3):
            w.append(make_record(f"f{i}", np.zeros((6, 2)), np.zeros((6, 2))))
    row = evaluate_runs([run_dir]).efficiency_rows()[0]
    assert row["run_wall_seconds"] is None and row["frames_per_second"] is None


def test_block_scoring_equals_one_call(two_runs, monkeypatch):
    """Scoring in blocks (bounded memory) gives the same numbers as one call over all frames."""
    import lightemma.evaluation.core as core

    out, a, b = two_runs
    whole = evaluate_runs([a], convention="all").to_dict()["accuracy"]
    monkeypatch.setattr(core, "SCORE_BLOCK", 7)
    blocks = evaluate_runs([a], convention="all").to_dict()["accuracy"]
    for convention in ("lightemma", "stp3", "uniad"):
        for key in ("ade_1s", "ade_2s", "ade_3s", "ade_avg", "fde", "miss_rate"):
            assert blocks[convention][0][key] == pytest.approx(whole[convention][0][key], rel=1e-12)


def test_unknown_convention_is_refused_before_reading(tmp_path):
    with pytest.raises(UserError, match="unknown convention 'nope'"):
        evaluate_runs([tmp_path / "not-even-there"], convention="nope")


def test_loading_restores_the_garbage_collector(two_runs, tmp_path):
    import gc

    out, a, b = two_runs
    assert gc.isenabled()
    load_run(a)
    assert gc.isenabled()
    gc.disable()
    try:
        load_run(a)
        assert not gc.isenabled()  # left as the caller had it
    finally:
        gc.enable()


def test_pairs_array_turns_bad_entries_into_nan():
    from lightemma.runs.columns import pairs_array

    good = [[1.0, 2], [3, 4.5]] * 3
    np.testing.assert_array_equal(pairs_array([good, good]), np.array([good, good], dtype=float))
    bad = [[[1, 2]] * 5, [[1, 2, 3]] * 6, "abcdef", [["a", "b"]] * 6, 5, [[1, 2]] * 7, [[None, 1]] * 6]
    out = pairs_array([good, *bad])
    assert np.isfinite(out[0]).all() and not np.isfinite(out[1:]).all(axis=(1, 2)).any()
    assert pairs_array([]).shape == (0, 6, 2)


def test_frames_with_only_api_errors_are_counted_apart_from_format_errors(tmp_path):
    from lightemma.runs.records import answer_received, first_answer_status

    run_dir = create_run_dir(tmp_path, "m", {"model": "m", "finished_at": "t"})
    gt = np.zeros((6, 2))
    api_error = make_record("f3", gt, None, status="failed", first_status=None)
    api_error["attempts"] = [{"answer": None, "status": "failed", "failure": "api_error", "reason": "API error: X"}] * 2
    legacy = make_record("f4", gt, None, status="failed")  # written before `failure` existed: first_status "failed"
    legacy["attempts"] = [{"answer": None, "status": "failed", "reason": "API error: X"}]
    late = make_record("f5", gt, np.ones((6, 2)), status="ok", first_status="failed")
    late["attempts"] = [
        {"answer": None, "status": "failed", "failure": "api_error"},
        {"answer": "[(…)]", "status": "corrected", "failure": ""},
    ]
    with RunWriter(run_dir) as w:
        w.append(make_record("f1", gt, np.ones((6, 2)), status="ok"))
        w.append(make_record("f2", gt, None, status="failed"))
        for rec in (api_error, legacy, late):
            w.append(rec)
    assert [answer_received(r) for r in (api_error, legacy, late)] == [False, False, True]
    assert first_answer_status(late) == "corrected" and first_answer_status(api_error) is None
    ev = evaluate_runs([run_dir])
    row = ev.accuracy_rows()[0]
    # over the three frames with an answer (ok, failed, corrected first): FE 2/3, FE corr 1/3
    assert row["fe_pct"] == pytest.approx(100 * 2 / 3) and row["fe_corr_pct"] == pytest.approx(100 / 3)
    assert row["api_errors"] == 2  # the frames that never received an answer, older records included
    assert row["failed"] == 1  # f2: an answer that failed to parse
    assert ev.models[0].accounting["failed_final"] == 3


def test_a_file_given_as_a_run_directory_is_named_as_a_file(two_runs, capsys):
    """Before: 'RUN/frames.jsonl does not exist', of a file that exists."""
    out, a, _ = two_runs
    for path in (a / FRAMES_FILE, a / "manifest.json"):
        assert main(["evaluate", str(path)]) == 2
        err = capsys.readouterr().err.strip()
        assert err == (
            f"lightemma evaluate: error: {path} is a file, not a run directory; give the folder that holds "
            f"manifest.json ({a})"
        ), err
    assert main(["evaluate", str(out / "missing")]) == 2
    assert capsys.readouterr().err.strip() == f"lightemma evaluate: error: {out / 'missing'} does not exist"
