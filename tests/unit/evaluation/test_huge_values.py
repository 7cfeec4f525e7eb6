"""`evaluate --keep-implausible` with huge finite answers (issue 19): never an abort, never a 309-digit number,
never a NumPy warning on stderr; a row whose values are too large to resample is computed, flagged, and says why
it has no interval."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

import lightemma
from lightemma.cli import main
from lightemma.evaluation.synthetic import make_record
from lightemma.runs.store import RunWriter, create_run_dir, update_manifest

GT = lightemma.integrate(np.array([[4.0, 0.0]] * 6))


def write_run(root, model, speeds):
    """A finished run: one frame per speed (constant actions), frames spread over 4 scenes; the answers are the lists."""
    run_dir = create_run_dir(root, model, {"model": model, "params": {"integrate_method": "euler"}})
    with RunWriter(run_dir) as writer:
        for i, v in enumerate(speeds):
            actions = np.array([[v, 0.0]] * 6)
            answer = "[" + ", ".join([f"({v!r}, 0.0)"] * 6) + "]"
            rec = make_record(
                f"scene-{i % 4}/{i}",
                GT,
                lightemma.integrate(actions),
                actions=actions,
                scene_name=f"scene-{i % 4}",
                texts={"answer": answer},
            )
            rec["attempts"][0].update(status="ok", reason="", failure="")
            writer.append(rec)
    update_manifest(run_dir, finished_at="t")
    return run_dir


def evaluate_json(capsys, *args):
    code = main(["evaluate", *map(str, args), "--keep-implausible", "--format", "json"])
    out, err = capsys.readouterr()
    assert code == 0, err
    assert "Warning" not in err and "overflow" not in err, err
    doc = json.loads(out)
    return [t for t in doc["tables"] if t["name"] == "accuracy_lightemma"][0], doc


def test_one_huge_answer_is_scored_with_an_interval(tmp_path, capsys):
    run_dir = write_run(tmp_path, "openai/huge", [1e200] + [4.0 + 0.1 * i for i in range(11)])
    table, _ = evaluate_json(capsys, run_dir)
    (row,) = table["rows"]
    assert row["scored"] == 12 and row["ade_avg"] == pytest.approx((1e200 * 3.5 * 0.5 - 0.0) / 12, rel=0.01)
    assert row["ade_avg_ci95"] is not None and row["ci95_unavailable"] is None
    for extra in ([], ["--resamples", "0"]):
        assert main(["evaluate", str(run_dir), "--keep-implausible", *extra]) == 0
        out, err = capsys.readouterr()
        assert not re.search(r"\d{20}", out) and "e+198" in out, out  # short scientific notation, never 200 digits
        assert "Warning" not in err, err
    # the parse reason names the value as briefly (a run that did not keep it)
    parsed = lightemma.parse_actions("[" + ", ".join(["(1e308, 0.0)"] * 6) + "]")
    assert parsed.reason[0] == "speed 1e308 at step 1 outside [-10, 50] m/s"


def test_values_too_large_to_resample_leave_the_row_computed_and_flagged(tmp_path, capsys):
    huge = write_run(tmp_path, "openai/huge", [1e307] * 8 + [4.0] * 4)
    calm = write_run(tmp_path, "openai/calm", [4.0 + 0.1 * i for i in range(12)])
    table, doc = evaluate_json(capsys, huge, calm, "--pairwise")
    rows = {r["model"]: r for r in table["rows"]}
    bad, good = rows["openai/huge"], rows["openai/calm"]
    assert bad["scored"] == 12 and np.isfinite(bad["ade_avg"]) and bad["ade_avg"] > 1e306
    assert (bad["ade_avg_ci95"], bad["fde_ci95"]) == (None, None)
    assert bad["ci95_unavailable"].startswith("interval unavailable: values too large to resample (ADE avg up to 1.")
    assert "e+307 m)" in bad["ci95_unavailable"]
    assert good["ade_avg_ci95"] is not None and good["ci95_unavailable"] is None  # the other rows are computed as usual
    assert any("openai/huge: interval unavailable" in n for n in table["notes"])
    pair = [t for t in doc["tables"] if t["name"] == "pairwise_ade"][0]["rows"][0]
    assert pair["ci95"] is None and pair["p_value"] is None and "too large to resample" in pair["note"]
    assert main(["evaluate", str(huge), str(calm), "--keep-implausible"]) == 0
    out, err = capsys.readouterr()
    assert "openai/huge (no interval)" in out and not re.search(r"\d{20}", out), out
    assert "Warning" not in err
