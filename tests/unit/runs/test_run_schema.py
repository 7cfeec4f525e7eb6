"""The typed run records (lightemma.runs.schema): every writer's records pass the schema, and the bytes a run writes
are those the code wrote before the types existed (tests/golden/run_records.json, tests/support/run_record_scenarios.py)."""

from __future__ import annotations

import json
import re

import pytest

from lightemma.runs.schema import (
    AttemptRecord,
    CallRecord,
    FrameRecord,
    RecordSchemaError,
    attempt_record,
    call_record,
    frame_record,
    schema_problem,
)
from lightemma.runs.store import FRAMES_FILE, read_run
from tests.support.fake_openai import FakeOpenAIServer, Reply
from tests.support.run_record_scenarios import GOLDEN, run_dirs, scenarios

pytestmark = pytest.mark.slow  # every writer runs once (~30 s)


@pytest.fixture(scope="module")
def written(tmp_path_factory, synth_root):
    """(scenario → normalized frames and manifest, scenario → records as written), from one run of every writer."""
    tmp = tmp_path_factory.mktemp("schema-runs")
    texts = scenarios(tmp / "golden", synth_root)
    dirs = run_dirs(tmp / "records", synth_root)
    records = {
        name: [json.loads(line) for line in (d / FRAMES_FILE).read_text().splitlines()] for name, d in dirs.items()
    }
    return texts, records


def test_every_writer_writes_the_bytes_it_wrote_before_the_record_types(written):
    texts, _ = written
    golden = json.loads(GOLDEN.read_text())
    assert set(texts) == set(golden)
    for name, want in golden.items():
        assert texts[name]["frames"] == want["frames"], f"{name}: frames.jsonl differs from the golden"
        assert texts[name]["manifest"] == want["manifest"], f"{name}: manifest.json differs from the golden"


def test_every_writers_records_pass_the_schema(written):
    _, records = written
    writers = {re.sub(r"_.*", "", name) for name in records}
    assert writers == {"baseline", "api", "batch", "import"}  # the chain over each backend kind, and the importer
    for name, lines in records.items():
        assert lines, name
        for record in lines:
            assert schema_problem(record) is None, f"{name}: {record['frame_id']}: {schema_problem(record)}"


def test_a_sampled_runs_records_pass_the_schema_with_their_samples(synth_root, tmp_path, monkeypatch):
    from lightemma.pipeline.runner import run

    def model(req):
        if req.stage == "scene":
            return Reply(choices=[f"Scene variant {i}." for i in range(req.body.get("n", 1))])
        if req.stage == "actions":
            return Reply("[" + ", ".join("(5.0, 0.0)" for _ in range(6)) + "]")
        return Reply("Keep.")

    monkeypatch.setenv("LIGHTEMMA_TEST_SCHEMA_KEY", "sk-test")
    with FakeOpenAIServer(model) as server:
        result = run(
            "openai/gpt-4o",
            dataroot=synth_root,
            version="v1.0-mini",
            split="all",
            api_base=server.url,
            api_key_env="LIGHTEMMA_TEST_SCHEMA_KEY",
            output=tmp_path,
            limit=2,
            samples=2,
            temperature=0.7,
            concurrency=1,
            progress=False,
        )
    records = list(read_run(result.run_dir).records.values())
    assert len(records) == 2 and all(len(r["samples"]) == 1 for r in records)
    for record in records:
        assert schema_problem(record) is None, schema_problem(record)


def _call(**change):
    fields = dict(
        stage="scene",
        text="t",
        error=None,
        error_message=None,
        input_tokens=10,
        output_tokens=5,
        seconds=0.5,
        cost_cents=None,
        cached=False,
        retries=0,
        finish_reason="stop",
        reasoning_tokens=None,
        cached_input_tokens=None,
        cache_write_tokens=None,
    )
    fields.update(change)
    return call_record(**{k: v for k, v in fields.items() if v != "<drop>"})


def _frame(**change):
    attempt = attempt_record(
        attempt=1,
        calls=[_call()],
        answer="a",
        status="ok",
        reason="",
        failure="",
        error=None,
        input_tokens=10,
        output_tokens=5,
        seconds=0.5,
        cost_cents=None,
    )
    fields = dict(
        frame_id="scene-0001/t",
        scene_name="scene-0001",
        sample_token="t",
        status="ok",
        failure="",
        first_status="ok",
        n_attempts=1,
        attempts=[attempt],
        actions=[[1.0, 0.0]] * 6,
        trajectory=[[0.5, 0.0]] * 6,
        gt_positions=[[0.5, 0.0]] * 6,
        history_actions=[[1, 0]] * 6,
        scene_text="s",
        intent_text="i",
        answer="a",
        error=None,
        seconds=1.0,
        call_seconds=0.5,
        input_tokens=10,
        output_tokens=5,
        cost_cents=None,
        cached=False,
        cached_calls=0,
        retries=0,
    )
    fields.update(change)
    return frame_record(**{k: v for k, v in fields.items() if v != "<drop>"})


def test_the_constructors_keep_the_writers_key_order_and_refuse_a_missing_or_undeclared_field():
    record = _frame()
    assert list(record)[:6] == ["frame_id", "scene_name", "sample_token", "status", "failure", "first_status"]
    swapped = {k: record[k] for k in ("frame_id", "scene_name", "sample_token", "status", "first_status")}
    swapped |= dict(record)
    assert list(frame_record(**swapped))[4:6] == ["first_status", "failure"]  # the importer's order, kept
    assert schema_problem(record) is None
    with pytest.raises(RecordSchemaError, match="FrameRecord lacks first_status"):
        _frame(first_status="<drop>")
    with pytest.raises(RecordSchemaError, match="FrameRecord has undeclared bogus"):
        _frame(bogus=1)
    with pytest.raises(RecordSchemaError, match="CallRecord lacks finish_reason"):
        _call(finish_reason="<drop>")
    _call(cache_write_tokens="<drop>")  # optional: imported calls have none


@pytest.mark.parametrize(
    "change, said",
    [
        (dict(seconds="1.0"), "seconds is str '1.0', expected float"),
        (dict(cached=1), "cached is int 1, expected bool"),
        (dict(n_attempts=1.0), "n_attempts is float 1.0, expected int"),
        (dict(status=None), "status is NoneType None, expected str"),
        (dict(actions=[[1.0, "x"]]), "actions[0][1] is str 'x'"),
        (dict(attempts=[{"attempt": 1}]), "attempts[0] lacks"),
    ],
)
def test_schema_problem_names_the_first_field_of_the_wrong_kind(change, said):
    record = dict(_frame())
    record.update(change)
    problem = schema_problem(record)
    assert problem is not None and said in problem, problem


def test_schema_problem_checks_inside_attempts_and_calls():
    record = json.loads(json.dumps(_frame()))
    record["attempts"][0]["calls"][0]["input_tokens"] = True
    assert schema_problem(record) == "attempts[0].calls[0].input_tokens is bool True, expected int"
    assert schema_problem([]) == "FrameRecord is list, expected an object"
    assert schema_problem(record["attempts"][0], AttemptRecord).startswith("calls[0].input_tokens")
    assert schema_problem(record["attempts"][0]["calls"][0], CallRecord) == "input_tokens is bool True, expected int"
    assert FrameRecord.__required_keys__ >= {"frame_id", "status", "first_status", "attempts"}
    assert "samples" in FrameRecord.__optional_keys__


def test_a_samples_entry_is_declared_with_exactly_the_fields_the_chain_copies():
    from lightemma.pipeline.chain import SAMPLE_FIELDS
    from lightemma.runs.schema import SampleRecord

    assert SampleRecord.__required_keys__ == {"sample", *SAMPLE_FIELDS}
