"""History-aware parsing end to end (issue 19): answers that recap the history the prompt gave, through the
loopback server, `run`, `resume`, the response cache, `evaluate --parse` and `import`.

A stage-3 answer that ends by quoting the frame's history (``For comparison, the past actions were [...]``)
must be read as the answer it gave, never as the history; a recap that is *not* the history (waypoints)
leaves two different lists, which is ``ambiguous``.
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

import lightemma
from lightemma.cli import main as cli_main
from lightemma.evaluation import evaluate_runs
from lightemma.evaluation.rescore import ParseDefinition, rescored
from lightemma.frames.render import format_history
from lightemma.pipeline import resume, run
from lightemma.runs.store import read_run
from tests.support.fake_openai import FakeOpenAIServer, Reply, default_reply
from tests.support.memframes import FrameIndex, make_frames

FAST = dict(backoff_base=0.01, backoff_cap=0.05, timeout=5.0, progress=False)
N = 6


def answer_of(i: int) -> np.ndarray:
    """Frame i's answer: slowing down and turning, far from its history."""
    return np.column_stack([np.linspace(9.0, 6.0, 6) + 0.1 * i, np.linspace(0.0, 0.05, 6)]).round(3)


def text_of(actions: np.ndarray) -> str:
    return "[" + ", ".join(f"({v!r}, {c!r})" for v, c in actions.tolist()) + "]"


@pytest.fixture
def frames(tmp_path):
    out = []
    for i, f in enumerate(make_frames(tmp_path, N)):
        # histories with decimals that do not round-trip through 3 digits, as real ones (docs/definitions.md#history)
        history = np.column_stack([4.5 + 0.1 * np.arange(6) + 0.0123 * i, 0.001 * np.arange(6) - 0.0021])
        out.append(dataclasses.replace(f, history_actions=history))
    return out


def recap_script(frames, recap):
    """Stage 3 answers frame i's answer, then ``recap(i, prompt)``; the prompt must hold the quoted history."""
    index = FrameIndex(frames)
    prompts = {}

    def script(req):
        if req.stage != "actions":
            return default_reply(req)
        i = index(req)
        prompts[i] = req.text
        return Reply(text_of(answer_of(i)) + "\n" + recap(i, req.text))

    return script, prompts


def history_recap(frames):
    def recap(i, prompt):
        quoted = format_history(frames[i].history_actions)
        assert quoted in prompt  # the model quotes what the prompt printed
        return f"For comparison, the past actions were {quoted}."

    return recap


def waypoint_recap(i, prompt):
    return "Waypoints: " + text_of(lightemma.integrate(answer_of(i)[None])[0].round(2))


def ade(actions, frames):
    gt = np.array([f.gt_positions for f in frames])
    return float(lightemma.evaluate(lightemma.integrate(np.asarray(actions, dtype=float)), gt).ade_avg)


def test_a_recap_of_the_history_after_the_answer_never_becomes_the_prediction(tmp_path, frames, capsys):
    script, prompts = recap_script(frames, history_recap(frames))
    with FakeOpenAIServer(script) as server:
        result = run(
            "openai/test-model", api_base=server.url, frames=frames, output=tmp_path / "runs", cache=True, **FAST
        )
        records = read_run(result.run_dir).records
        assert len(prompts) == N
        for i, f in enumerate(frames):
            rec = records[f.frame_id]
            assert (rec["status"], rec["failure"], rec["n_attempts"]) == ("corrected", "", 1), rec["attempts"][0][
                "reason"
            ]
            np.testing.assert_array_equal(rec["actions"], answer_of(i))
            assert "skipped 1 list(s) repeating the history given in the prompt" in rec["attempts"][0]["reason"]
        want = ade([answer_of(i) for i in range(N)], frames)
        history_ade = ade([f.history_actions for f in frames], frames)
        assert result.summary["ade_avg"] == pytest.approx(want) and abs(want - history_ade) > 0.5
        # the response cache replays the same answers: parsed with the same histories
        replay = run(
            "openai/test-model", api_base=server.url, frames=frames, output=tmp_path / "runs", cache=True, **FAST
        )
        assert len(server.requests) == 3 * N  # the second run was served from the cache
    again = read_run(replay.run_dir).records
    assert all(r["cached"] and r["status"] == "corrected" for r in again.values())
    for i, f in enumerate(frames):
        np.testing.assert_array_equal(again[f.frame_id]["actions"], answer_of(i))
    # evaluate, as recorded and re-parsed (lenient with the histories; strict: none is the bare list)
    for extra in ([], ["--parse", "lenient"]):
        assert cli_main(["evaluate", str(result.run_dir), *extra, "--format", "json", "--resamples", "0"]) == 0
        doc = json.loads(capsys.readouterr().out)
        row = [t for t in doc["tables"] if t["name"] == "accuracy_lightemma"][0]["rows"][0]
        assert (row["scored"], row["failed"]) == (N, 0)
        assert row["ade_avg"] == pytest.approx(want, abs=1e-3)
    ev = evaluate_runs([result.run_dir], parse=ParseDefinition("strict"))
    assert ev.accuracy_rows()[0]["fe_corr_pct"] == 100.0


def test_a_recap_that_is_not_the_history_is_ambiguous_and_resume_keeps_it_so(tmp_path, frames, capsys):
    script, _ = recap_script(frames, waypoint_recap)
    with FakeOpenAIServer(script) as server:
        result = run(
            "openai/test-model", api_base=server.url, frames=frames, output=tmp_path / "runs", max_attempts=2, **FAST
        )
        for rec in read_run(result.run_dir).records.values():
            assert (rec["status"], rec["failure"], rec["n_attempts"]) == ("failed", "ambiguous", 2)
            assert rec["attempts"][0]["reason"].startswith(
                "ambiguous: 2 different lists of 6 actions (at positions 0 and "
            )
        assert (result.summary["failed"], result.summary["ade_frames"]) == (N, 0)
        retried = resume(result.run_dir, retry_failed=True, frames=frames, progress=False, api_base=server.url)
    assert all(r["failure"] == "ambiguous" for r in read_run(retried.run_dir).records.values())
    assert cli_main(["evaluate", str(result.run_dir), "--format", "json", "--resamples", "0"]) == 0
    row = [t for t in json.loads(capsys.readouterr().out)["tables"] if t["name"] == "accuracy_lightemma"][0]["rows"][0]
    assert (row["scored"], row["failed"], row["ade_avg"]) == (0, N, None)


def test_rescoring_passes_each_records_own_history(frames):
    """`evaluate --parse` re-reads every attempt with its frame's history; a record without one is read without."""
    records = []
    for i, f in enumerate(frames):
        answer = text_of(answer_of(i)) + "\nPast: " + format_history(f.history_actions)
        records.append(
            {
                "frame_id": f.frame_id,
                "status": "failed",
                "failure": "format",
                "history_actions": f.history_actions.tolist(),
                "attempts": [{"answer": answer, "status": "failed", "reason": ""}],
                "answer": answer,
            }
        )
    records[-1] = {k: v for k, v in records[-1].items() if k != "history_actions"}
    out = list(rescored(records, ParseDefinition("lenient"), block=4))  # blocks split the batch: rows stay aligned
    for i, rec in enumerate(out[:-1]):
        assert rec["status"] == "corrected", rec["attempts"][0]["reason"]
        np.testing.assert_array_equal(rec["actions"], answer_of(i))
    assert (out[-1]["status"], out[-1]["failure"]) == ("failed", "ambiguous")


def test_an_answer_equal_to_the_history_is_scored_as_given(frames):
    """Issue 32: keeping one's pace is an answer. A final answer equal to the history is taken after a draft (the
    history rule used to skip it and score the draft); the history followed by another list with nothing calling
    it the past is ambiguous (it used to score the other list: a degenerate one in a real deepseek-vl2-16b answer)."""
    degenerate = np.column_stack([np.linspace(0.005, 0.027, 6), np.linspace(0.005, 0.027, 6)]).round(3)
    records = []
    for i, f in enumerate(frames):
        quoted = format_history(f.history_actions)
        answer = {
            0: f"Draft: {text_of(answer_of(i))}\nFinal answer: {quoted}",
            1: f"{quoted}\n{text_of(degenerate)}",
            2: f"The previous actions were {quoted}. Now: {text_of(degenerate)}",
        }[i % 3]
        records.append(
            {
                "frame_id": f.frame_id,
                "status": "failed",
                "failure": "format",
                "history_actions": f.history_actions.tolist(),
                "attempts": [{"answer": answer, "status": "failed", "reason": ""}],
                "answer": answer,
            }
        )
    out = list(rescored(records, ParseDefinition("lenient"), block=4))
    for i, (f, rec) in enumerate(zip(frames, out)):
        reason = rec["attempts"][0]["reason"]
        if i % 3 == 0:
            assert rec["status"] == "corrected", reason
            np.testing.assert_allclose(rec["actions"], f.history_actions, rtol=0, atol=1e-12)
            assert (
                "the list equals the history given in the prompt" in reason and "took the list after the cue" in reason
            )
        elif i % 3 == 1:
            assert (rec["status"], rec["failure"]) == ("failed", "ambiguous"), reason
        else:
            assert rec["status"] == "corrected", reason
            np.testing.assert_array_equal(rec["actions"], degenerate)


def test_history_rows_and_the_shape_check():
    rows = lightemma.actions.history_rows([np.zeros((6, 2)), None, [[1, 2]], np.full((6, 2), np.inf)])
    assert rows.shape == (4, 6, 2) and (rows[0] == 0).all() and np.isnan(rows[1:]).all()
    with pytest.raises(ValueError, match=r"history must have shape \(2, 6, 2\)"):
        lightemma.parse_actions(["a", "b"], history=np.zeros((1, 6, 2)))
    # a row of NaN equals nothing; the other modes ignore the history
    text = "Past: " + text_of(np.zeros((6, 2)))
    assert lightemma.parse_actions(text, history=np.full((1, 6, 2), np.nan)).status[0] == "corrected"
    assert "the list equals the history" in lightemma.parse_actions(text, history=np.zeros((1, 6, 2))).reason[0]
    assert (
        lightemma.parse_actions(text + " then " + text.replace("0.0)", "0.5)", 1), history=np.zeros((1, 6, 2))).status[
            0
        ]
        == "corrected"
    )
    assert lightemma.parse_actions(text, mode="paper", history=np.zeros((1, 6, 2))).status[0] == "corrected"


def test_every_parse_failure_kind_is_known_to_evaluation():
    """A new parse failure kind (``ambiguous``) is counted as failed, never mistaken for another kind."""
    from lightemma.definitions import OUTCOME_CODES, PARSE_FAILURES, UNREADABLE
    from lightemma.evaluation.outcomes import outcome_counts
    from lightemma.runs.columns import failure_code

    assert set(PARSE_FAILURES) <= set(OUTCOME_CODES)
    assert "ambiguous" in UNREADABLE and failure_code("ambiguous") not in (
        failure_code("format"),
        failure_code("implausible"),
    )
    codes = np.array([failure_code(k) for k in ("", "ambiguous", "format", "truncated", "implausible", "api_error")])
    counts = outcome_counts(codes, codes == 0)
    assert counts == {"scored": 1, "failed": 3, "implausible": 1, "api_errors": 1}
