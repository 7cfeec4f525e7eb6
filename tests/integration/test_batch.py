"""``lightemma run --batch``: the chain through each provider's batch endpoints, emulated on 127.0.0.1 (tests/support/fake_batch.py).

Waves, custom ids, results in shuffled order, partial failures, expiry, a batch rejected as a whole, the
journal, and a run killed mid-poll then resumed without a new batch for what was already submitted.
"""

from __future__ import annotations

import base64
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

import lightemma
import lightemma.backends.batch as batch_module
from lightemma.backends.batch.journal import BatchJournal
from lightemma.errors import RunStopped, UserError
from lightemma.pipeline.runner import resume, run
from lightemma.runs.store import read_run
from tests.support.fake_batch import FakeBatchServer

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(autouse=True)
def _fast(monkeypatch):
    monkeypatch.setattr(
        batch_module, "IDLE_SECONDS", 0.15
    )  # a wave closes after this idle time: room for a loaded CI machine
    monkeypatch.setenv("OPENAI_API_KEY", "sk-test-openai")
    monkeypatch.setenv("ANTHROPIC_API_KEY", "sk-ant-test")
    monkeypatch.setenv("GEMINI_API_KEY", "gm-test-key")


def _run(synth_root, tmp_path, model, **kw):
    kw.setdefault("sample", 4)
    return run(
        model,
        dataroot=synth_root,
        version="v1.0-mini",
        split="all",
        output=tmp_path / "runs",
        batch=True,
        batch_poll=0.01,
        progress=False,
        **kw,
    )


def _records(run_dir):
    return read_run(run_dir).records


def _journal_lines(run_dir):
    return [json.loads(line) for line in (Path(run_dir) / "batches.jsonl").read_text().splitlines()]


def _stage_of(server, custom_id):
    """The stage a request of the fake server asked for, from its custom id."""
    from tests.support.fake_openai import Received

    for batch in server.batches.values():
        for cid, body in batch.requests:
            if cid == custom_id:
                path = {
                    "openai": "/v1/chat/completions",
                    "anthropic": "/v1/messages",
                    "gemini": "/v1beta/models/m:generateContent",
                }[batch.protocol]
                return Received(path=path, headers={}, body=body, index=0).stage
    raise KeyError(custom_id)


def test_openai_batch_runs_three_waves_at_batch_price_with_shuffled_results(tmp_path, synth_root):
    with FakeBatchServer(steps=3, shuffle=True, seed=7) as server:
        result = _run(synth_root, tmp_path, "openai/gpt-4o", api_base=server.url)
    records = _records(result.run_dir)
    assert len(records) == 4 and all(r["status"] == "ok" for r in records.values())
    # one wave per stage: every frame's stage 1 in the first batch, stage 2 in the second, stage 3 in the third
    assert server.created == 3
    stages = [{_stage_of(server, cid) for cid, _ in b.requests} for b in server.batches.values()]
    assert stages == [{"scene"}, {"intent"}, {"actions"}]
    # shuffled results are matched by custom id: each frame got its own stage's text
    for rec in records.values():
        texts = [c["text"] for c in rec["attempts"][0]["calls"]]
        assert (
            texts[0].startswith("A two-lane")
            and texts[1].startswith("The ego vehicle")
            and texts[2].startswith("[(5.0")
        )
    # OpenAI's batch price is half its list price: 1000 in, 50 out per call at $1.25 / $5 per M tokens
    call = next(iter(records.values()))["attempts"][0]["calls"][0]
    assert call["cost_cents"] == pytest.approx((1000 * 1.25 + 50 * 5.0) / 1e6 * 100)
    manifest = json.loads((result.run_dir / "manifest.json").read_text())
    assert manifest["config"]["batch"] is True and manifest["backend"]["mode"] == "batch"
    report = manifest["sessions"][-1]["batch"]
    assert report["batches_created"] == 3 and report["waves"] == 3 and len(report["turnaround_s"]) == 3
    events = [e["event"] for e in _journal_lines(result.run_dir)]
    assert events == ["submitting", "submitted", "completed"] * 3
    # the gpt-4o batch body: max_completion_tokens, the model's own name
    body = next(iter(server.batches.values())).requests[0][1]
    assert body["model"] == "gpt-4o" and "max_completion_tokens" in body and "max_tokens" not in body


def test_a_failed_request_is_reasked_in_a_later_wave_and_an_expired_one_resubmitted(tmp_path, synth_root):
    with FakeBatchServer(steps=1) as probe:  # learn the custom ids of the first wave
        first = _run(synth_root, tmp_path / "probe", "openai/gpt-4o", api_base=probe.url)
    first_wave = [cid for cid, _ in next(iter(probe.batches.values())).requests]
    failing, expiring = first_wave[0], first_wave[1]
    with FakeBatchServer(steps=1, fail={failing: "image could not be decoded"}, expire={expiring}) as server:
        result = _run(synth_root, tmp_path, "openai/gpt-4o", api_base=server.url)
    records = _records(result.run_dir)
    assert all(r["status"] == "ok" for r in records.values())
    failed = [r for r in records.values() if r["n_attempts"] == 2]
    assert len(failed) == 1  # the errored request was an API error of attempt 1; attempt 2 succeeded
    assert failed[0]["attempts"][0]["calls"][0]["error"] == "BatchRequestError"
    assert "image could not be decoded" in failed[0]["attempts"][0]["calls"][0]["error_message"]
    # the expired request was sent again under a new custom id, without costing an attempt
    resent = [cid for b in server.batches.values() for cid, _ in b.requests if cid == expiring + "-r1"]
    assert resent and sum(1 for r in records.values() if r["n_attempts"] == 1) == 3
    manifest = json.loads((result.run_dir / "manifest.json").read_text())
    assert manifest["sessions"][-1]["batch"]["requests_resubmitted"] == 1
    assert first.run_dir != result.run_dir


def test_a_batch_rejected_as_a_whole_stops_the_run_with_its_reason(tmp_path, synth_root):
    with FakeBatchServer(steps=1, batch_state="failed") as server:
        with pytest.raises(RunStopped) as stopped:
            _run(synth_root, tmp_path, "openai/gpt-4o", api_base=server.url)
    assert stopped.value.cause == "batch-failed"
    assert "line 1: bad model" in str(stopped.value) and "--resume" in str(stopped.value)
    assert server.created == 1  # not resubmitted wave after wave


@pytest.mark.parametrize(
    "model, env",
    [("anthropic/claude-sonnet-4-6", "ANTHROPIC_API_BASE"), ("gemini/gemini-2.5-flash", "GEMINI_API_BASE")],
)
def test_anthropic_and_gemini_batches_with_partial_failure_and_expiry(tmp_path, synth_root, monkeypatch, model, env):
    with FakeBatchServer(steps=1) as probe:
        monkeypatch.setenv(env, probe.root)
        _run(synth_root, tmp_path / "probe", model)
    first_wave = [cid for cid, _ in next(iter(probe.batches.values())).requests]
    with FakeBatchServer(steps=2, fail={first_wave[0]: "overloaded request"}, expire={first_wave[1]}) as server:
        monkeypatch.setenv(env, server.root)
        result = _run(synth_root, tmp_path, model)
    records = _records(result.run_dir)
    assert len(records) == 4 and all(r["status"] == "ok" for r in records.values())
    protocols = {b.protocol for b in server.batches.values()}
    assert protocols == {model.split("/")[0]}
    errored = [r for r in records.values() if r["n_attempts"] == 2]
    assert len(errored) == 1 and "overloaded request" in errored[0]["attempts"][0]["calls"][0]["error_message"]
    assert any(cid == first_wave[1] + "-r1" for b in server.batches.values() for cid, _ in b.requests)
    # the image went in the provider's own shape
    body = next(iter(server.batches.values())).requests[0][1]
    parts = body["messages"][0]["content"] if "messages" in body else body["contents"][0]["parts"]
    assert any(p.get("type") == "image" or "inline_data" in p for p in parts)
    rec = next(iter(records.values()))
    call = rec["attempts"][-1]["calls"][-1]
    price = {"anthropic": (1.5, 7.5), "gemini": (0.15, 1.25)}[model.split("/")[0]]
    assert call["cost_cents"] == pytest.approx((1000 * price[0] + 50 * price[1]) / 1e6 * 100)


def test_batch_is_refused_for_local_models_and_structured_answers_off_openai(tmp_path, synth_root):
    with pytest.raises(UserError, match="--batch is for models behind a provider's API"):
        _run(synth_root, tmp_path, "baseline:cv")
    with pytest.raises(UserError, match="--cache, --rpm do\\(es\\) not apply to --batch"):
        _run(synth_root, tmp_path, "openai/gpt-4o", api_base="http://127.0.0.1:9/v1", cache=True, rpm=10)
    with pytest.raises(UserError, match="only\\s+to OpenAI"):
        _run(synth_root, tmp_path, "anthropic/claude-sonnet-4-6", answer_format="structured")


def test_the_journal_ignores_a_torn_last_line_and_refuses_damage(tmp_path):
    journal = BatchJournal.open(tmp_path)
    journal.submitting("t1", ["a", "b"])
    journal.submitted("t1", "batch_1", ["a", "b"])
    with open(journal.path, "ab") as fh:
        fh.write(b'{"event":"submitting","tok')  # killed mid-write
    again = BatchJournal.open(tmp_path)
    assert again.by_custom_id == {"a": "batch_1", "b": "batch_1"} and not again.unconfirmed
    journal.path.write_text('not json\n{"event":"submitting","token":"t","custom_ids":[]}\n')
    with pytest.raises(UserError, match="damaged"):
        BatchJournal.open(tmp_path)


def test_an_interrupted_submission_is_found_by_its_token_not_resubmitted(tmp_path, synth_root, monkeypatch):
    """Killed between the provider creating a batch and the journal naming it: the resume finds it by its token."""
    calls = {"n": 0}
    original = BatchJournal.submitted

    def killed_once(self, token, batch_id, custom_ids):
        calls["n"] += 1
        if calls["n"] == 1:
            raise KeyboardInterrupt  # the process dies right after the provider created the batch
        return original(self, token, batch_id, custom_ids)

    monkeypatch.setattr(BatchJournal, "submitted", killed_once)
    with FakeBatchServer(steps=1) as server:
        with pytest.raises(KeyboardInterrupt):
            _run(synth_root, tmp_path, "openai/gpt-4o", api_base=server.url)
        run_dir = next((tmp_path / "runs").glob("*/*"))
        assert [e["event"] for e in _journal_lines(run_dir)] == ["submitting"] and server.created == 1
        resume(run_dir, progress=False, api_base=server.url)
    assert server.created == 3  # the first batch was found by its token; only stages 2 and 3 were submitted
    assert all(r["status"] == "ok" for r in _records(run_dir).values())


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "lightemma", "run", *args]


@pytest.mark.slow
@pytest.mark.parametrize("provider", ["openai", "anthropic", "gemini"])
def test_a_run_killed_mid_poll_resumes_by_polling_the_same_batches(tmp_path, synth_root, monkeypatch, provider):
    """Killed while polling the stage-2 batch: the resume reads stage 1 from the journal's saved results, polls
    the same stage-2 batch again (results shuffled, matched by custom id) and creates only the stage-3 batch."""
    model = {
        "openai": "openai/gpt-4o",
        "anthropic": "anthropic/claude-sonnet-4-6",
        "gemini": "gemini/gemini-2.5-flash",
    }[provider]
    env = {**os.environ, "PYTHONPATH": str(ROOT / "python"), "LITELLM_LOCAL_MODEL_COST_MAP": "True"}
    with FakeBatchServer(
        steps=2, shuffle=True, seed=3, hold_from=2
    ) as server:  # the stage-2 batch never ends while the run lives
        where = ["--api-base", server.url] if provider == "openai" else []
        if provider != "openai":
            base = {"anthropic": "ANTHROPIC_API_BASE", "gemini": "GEMINI_API_BASE"}[provider]
            env[base] = server.root
            monkeypatch.setenv(base, server.root)
        proc = subprocess.Popen(
            _cli(
                "--model",
                model,
                *where,
                "--dataroot",
                str(synth_root),
                "--version",
                "v1.0-mini",
                "--split",
                "all",
                "--sample",
                "4",
                "--batch",
                "--batch-poll",
                "0.2",
                "--output",
                str(tmp_path / "runs"),
                "--no-progress",
            ),
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
        )
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and not (server.created >= 2 and server.polls >= server.steps + 2):
            time.sleep(0.1)
        assert server.created == 2, proc.communicate(timeout=5)
        proc.send_signal(signal.SIGKILL)  # mid-poll of the stage-2 batch
        proc.wait(timeout=10)
        run_dir = next((tmp_path / "runs").glob("*/*"))
        assert [e["event"] for e in _journal_lines(run_dir)] == [
            "submitting",
            "submitted",
            "completed",
            "submitting",
            "submitted",
        ]
        assert _records(run_dir) == {}
        first, second = list(server.batches.values())
        first_polls = first.polls
        server.hold_from = None  # the provider finishes the stage-2 batch now
        # in this process: the same code as `lightemma run --resume`, one start-up less; the endpoint as the run had it
        resume(run_dir, progress=False, api_base=server.url if provider == "openai" else None)
    assert server.created == 3  # stage 1 and 2 never resubmitted; only stage 3 is new
    assert first.polls == first_polls  # stage 1 answered from the saved results, not even polled
    assert second.polls >= server.steps
    records = _records(run_dir)
    assert len(records) == 4 and all(r["status"] == "ok" for r in records.values())
    for rec in records.values():  # each frame got its own answers back, whatever order they came in
        assert [c["stage"] for c in rec["attempts"][0]["calls"]] == ["scene", "intent", "actions"]
        assert rec["attempts"][0]["calls"][1]["text"].startswith("The ego vehicle")
    manifest = json.loads((run_dir / "manifest.json").read_text())
    assert manifest["sessions"][-1]["batch"]["batches_resumed"] == 2
    assert manifest["sessions"][-1]["batch"]["batches_created"] == 1


def test_table_one_marks_a_batch_run_and_shows_run_names(tmp_path, synth_root):
    from lightemma.evaluation import evaluate_runs
    from lightemma.report.evaluation_tables import efficiency_table
    from lightemma.report.tables import to_markdown

    with FakeBatchServer(steps=1) as server:
        batch = _run(synth_root, tmp_path, "openai/gpt-4o", api_base=server.url, name="half-price")
    assert "time/frame    n/a (batch mode" in batch.report()
    normal = run(
        "baseline:cv",
        dataroot=synth_root,
        version="v1.0-mini",
        split="all",
        output=tmp_path / "runs",
        progress=False,
        sample=4,
        name="reference ego",
    )
    table = to_markdown(efficiency_table(evaluate_runs([batch.run_dir, normal.run_dir])))
    rows = {
        line.split("|")[1].strip(): [c.strip() for c in line.split("|")[1:-1]]
        for line in table.splitlines()
        if line.startswith("| ") and "Model" not in line
    }
    header = [c.strip() for c in next(line for line in table.splitlines() if "Model" in line).split("|")[1:-1]]
    assert set(rows) == {'openai/gpt-4o "half-price"', 'Baseline (constant velocity) "reference ego"'}
    batch_row = dict(zip(header, rows['openai/gpt-4o "half-price"']))
    assert batch_row["Time/frame (s)"] == "n/a" and batch_row["Batch turnaround (s)"] not in ("-", "n/a")
    other = dict(zip(header, rows['Baseline (constant velocity) "reference ego"']))
    assert other["Time/frame (s)"] != "n/a" and other["Batch turnaround (s)"] == "-"
    assert "Batch runs" in table


def test_max_cost_in_batch_mode_admits_whole_frames_and_a_resume_submits_only_the_rest(tmp_path, synth_root):
    from lightemma.pipeline.runner import estimate_run
    from lightemma.runs.store import read_frame_ids

    with FakeBatchServer(steps=1) as server:
        probe = _run(synth_root, tmp_path / "probe", "openai/gpt-4o", api_base=server.url)
    frames = lightemma.load_frames(synth_root, "v1.0-mini", split="all").select(read_frame_ids(probe.run_dir))
    per_frame = (
        estimate_run("openai/gpt-4o", frames=frames).batch_cost_cents / 4
    )  # the estimate's batch cost of one frame
    with FakeBatchServer(steps=1) as server:
        with pytest.raises(RunStopped) as stopped:
            _run(synth_root, tmp_path, "openai/gpt-4o", api_base=server.url, max_cost_cents=2.5 * per_frame)
        assert stopped.value.cause == "budget"
        run_dir = stopped.value.run_dir
        records = _records(run_dir)
        assert len(records) == 2 and all(
            r["status"] == "ok" for r in records.values()
        )  # two whole frames, all 3 stages
        assert [len(b.requests) for b in server.batches.values()] == [2, 2, 2]
        resume(run_dir, progress=False, max_cost_cents=100 * per_frame, api_base=server.url)
    assert len(_records(run_dir)) == 4
    assert [len(b.requests) for b in server.batches.values()] == [2, 2, 2, 2, 2, 2]  # only the two frames not yet run


def test_a_wave_is_split_within_the_providers_limits(tmp_path, synth_root, monkeypatch):
    from lightemma.backends.batch.openai import OpenAIBatches

    monkeypatch.setattr(OpenAIBatches, "max_requests", 3)
    with FakeBatchServer(steps=1) as server:
        result = _run(synth_root, tmp_path / "n", "openai/gpt-4o", api_base=server.url)
    assert [len(b.requests) for b in server.batches.values()] == [3, 1, 3, 1, 3, 1]
    assert all(r["status"] == "ok" for r in _records(result.run_dir).values())
    monkeypatch.setattr(OpenAIBatches, "max_requests", 50_000)
    monkeypatch.setattr(OpenAIBatches, "max_bytes", 1)  # every entry is larger: one request per batch
    with FakeBatchServer(steps=1) as server:
        _run(synth_root, tmp_path / "b", "openai/gpt-4o", api_base=server.url, sample=2)
    assert [len(b.requests) for b in server.batches.values()] == [1] * 6


@pytest.mark.parametrize(
    "model, env, variable",
    [
        ("anthropic/claude-sonnet-4-6", "ANTHROPIC_API_BASE", "ANTHROPIC_API_KEY"),
        ("gemini/gemini-2.5-flash", "GEMINI_API_BASE", "GEMINI_API_KEY"),
    ],
)
def test_a_rejected_key_stops_the_batch_run_at_once_and_journals_nothing_as_pending(
    tmp_path, synth_root, monkeypatch, model, env, variable
):
    with FakeBatchServer(steps=1, require_key="the-right-key") as server:
        monkeypatch.setenv(env, server.root)
        with pytest.raises(RunStopped) as stopped:
            _run(synth_root, tmp_path, model)
        assert stopped.value.cause == "authentication" and "rejected the key" in str(stopped.value)
        assert server.created == 0 and len(server.keys) == 1  # one refused call, no retries
        assert os.environ[variable] in server.keys[0]  # the key went in the provider's own header
        run_dir = stopped.value.run_dir
        assert [e["event"] for e in _journal_lines(run_dir)] == ["submitting", "abandoned"]
        monkeypatch.setenv(variable, "the-right-key")
        resume(run_dir, progress=False)
    assert len(_records(run_dir)) == 4 and server.created == 3


def test_an_expired_openai_batch_has_its_unrun_requests_resubmitted(tmp_path, synth_root):
    # an expired batch: the requests it reached are answered (output file), the others come back batch_expired
    with FakeBatchServer(steps=1, batch_state="expired") as server:
        result = _run(synth_root, tmp_path, "openai/gpt-4o", api_base=server.url, sample=2)
    records = _records(result.run_dir)
    resubmitted = json.loads((result.run_dir / "manifest.json").read_text())["sessions"][-1]["batch"][
        "requests_resubmitted"
    ]
    sent = [cid for b in server.batches.values() for cid, _ in b.requests]
    assert resubmitted >= 3 and len(sent) == 6 + resubmitted  # each expired request went out again under a new id
    assert all(cid.rsplit("-r", 1)[-1] in ("1", "2") for cid in sent if "-r" in cid)  # twice at most
    states = {e["state"] for e in _journal_lines(result.run_dir) if e["event"] == "completed"}
    assert states == {"expired"}
    # two resubmits were not always enough: such a request fails as BatchExpired, with its reason, and is re-asked
    calls = [c for r in records.values() for a in r["attempts"] for c in a["calls"]]
    expired = [c for c in calls if c["error"] == "BatchExpired"]
    assert all("batch_expired" in c["error_message"] for c in expired)
    assert all(r["status"] == "ok" for r in records.values()) and len(records) == 2


# -- keys and endpoints: the API backend's rule (issue 25), in batch mode too --------------------------------

PROVIDER_KEYS = {"openai": "OPENAI_API_KEY", "anthropic": "ANTHROPIC_API_KEY", "gemini": "GEMINI_API_KEY"}
BATCH_MODELS = ["openai/gpt-4o", "anthropic/claude-sonnet-4-6", "gemini/gemini-2.5-flash"]


def _provider_keys_in(headers):
    return {name for name in PROVIDER_KEYS.values() for h in headers if os.environ[name] in h}


@pytest.mark.parametrize("model", BATCH_MODELS)
def test_the_providers_own_host_gets_its_key_and_no_other(tmp_path, synth_root, model):
    """127.0.0.1 is declared each provider's own host (tests/conftest.py): its --api-base gets that provider's key."""
    provider = model.split("/")[0]
    with FakeBatchServer(steps=1) as server:
        result = _run(
            synth_root, tmp_path, model, api_base=server.url if provider == "openai" else server.root, sample=2
        )
    assert all(r["status"] == "ok" for r in _records(result.run_dir).values())
    assert {b.protocol for b in server.batches.values()} == {provider}  # the provider's own batch protocol
    assert server.keys and all(os.environ[PROVIDER_KEYS[provider]] in k for k in server.keys)
    assert _provider_keys_in(server.keys) == {PROVIDER_KEYS[provider]}


@pytest.mark.parametrize("model", BATCH_MODELS)
def test_a_batch_run_against_another_api_base_sends_no_provider_key(
    elsewhere, tmp_path, synth_root, monkeypatch, model
):
    with FakeBatchServer(steps=1) as server:
        result = _run(synth_root, tmp_path / "a", model, api_base=server.url, sample=2)
        records = _records(result.run_dir)
        assert len(records) == 2 and all(r["status"] == "ok" for r in records.values())
        assert {b.protocol for b in server.batches.values()} == {"openai"}  # another server speaks OpenAI's protocol
        assert server.keys and _provider_keys_in(server.keys) == set()
        # not the provider: no batch list price either
        assert all(c["cost_cents"] is None for r in records.values() for a in r["attempts"] for c in a["calls"])
        # a key variable named for that server: its key goes there, and still no provider's
        monkeypatch.setenv("MY_SERVER_KEY", "sk-my-own-server-key-0123456789")
        seen = len(server.keys)
        _run(synth_root, tmp_path / "b", model, api_base=server.url, api_key_env="MY_SERVER_KEY", sample=2)
        named = server.keys[seen:]
        assert named and all("sk-my-own-server-key-0123456789" in k for k in named)
        assert _provider_keys_in(named) == set()


def test_credentials_in_the_api_base_reach_the_server_but_no_journal_record_or_message(tmp_path, synth_root):
    with FakeBatchServer(steps=1) as server:
        base = server.url.replace("http://", "http://alice:hunter2pw@")
        result = _run(synth_root, tmp_path, "openai/gpt-4o", api_base=base, sample=2)
        assert all(r["status"] == "ok" for r in _records(result.run_dir).values())
        basic = "Basic " + base64.b64encode(b"alice:hunter2pw").decode()
        assert server.keys and set(server.keys) == {basic}  # used to reach the server, on every call
        # a server that refuses, echoing the URL it was asked at: the reason is journaled, the password is not
        server.require_key, server.refusal = "a-key-never-sent", "bad key at http://alice:hunter2pw@host"
        with pytest.raises(RunStopped) as stopped:
            _run(synth_root, tmp_path, "openai/gpt-4o", api_base=base, sample=2, name="refused")
    run_dir = stopped.value.run_dir
    abandoned = [e for e in _journal_lines(run_dir) if e["event"] == "abandoned"]
    assert len(abandoned) == 1 and "bad key at" in abandoned[0]["reason"]
    written = b"".join(p.read_bytes() for p in (tmp_path / "runs").rglob("*") if p.is_file())
    assert b"hunter2pw" not in written and "hunter2pw" not in str(stopped.value)
    assert (
        b"hunter2pw" not in (run_dir / "batches.jsonl").read_bytes()
        and b"hunter2pw" not in (result.run_dir / "batches.jsonl").read_bytes()
    )


# -- what a batch API's replies may be (issue 25.9) -----------------------------------------------------------

BATCH_MODEL = {
    "openai": "openai/gpt-4o",
    "anthropic": "anthropic/claude-sonnet-4-6",
    "gemini": "gemini/gemini-2.5-flash",
}


def _at(server, provider):
    return server.url if provider == "openai" else server.root


@pytest.mark.parametrize("provider", ["openai", "anthropic", "gemini"])
def test_a_batch_reply_past_its_limit_stops_the_run_in_one_line_and_a_resume_reads_the_same_batch(
    tmp_path, synth_root, monkeypatch, provider
):
    """A results file (a Gemini status poll: the results are inlined in it) past the limit for its batch: the run
    stops naming the limit, nothing was read into a record, and the resume polls the same batch, never resubmits."""
    from lightemma.backends.batch import adapter

    monkeypatch.setattr(adapter, "MIN_REPLY_BYTES", 64 << 10)  # 64 KiB + 1 KiB per request, instead of 64 MiB + 256 KiB
    monkeypatch.setattr(adapter, "RESULT_BYTES_PER_REQUEST", 1 << 10)
    with FakeBatchServer(steps=1, bloat=40 << 10) as server:  # 4 answers of 40 KiB each: 160 KiB > 68 KiB
        with pytest.raises(RunStopped) as stopped:
            _run(synth_root, tmp_path, BATCH_MODEL[provider], api_base=_at(server, provider))
        message = str(stopped.value).splitlines()[0]
        assert "more than the 65,536 bytes lightemma reads" in message and "a batch of 4 request(s)" in message, message
        assert "--resume" in message and server.created == 1
        run_dir = stopped.value.run_dir
        assert _records(run_dir) == {} and not (run_dir / "batch_results").exists()
        server.bloat = 0  # the provider's reply is readable now (say, the limit was raised between the sessions)
        for batch in server.batches.values():
            batch.results = None  # computed again, without the padding
        resume(run_dir, progress=False, api_base=_at(server, provider))
    assert server.created == 3  # the stage-1 batch was read, not submitted again
    assert len(_records(run_dir)) == 4 and all(r["status"] == "ok" for r in _records(run_dir).values())


@pytest.mark.parametrize("provider", ["openai", "anthropic", "gemini"])
def test_results_holding_a_request_twice_stop_the_run_never_pick_one(tmp_path, synth_root, provider):
    with FakeBatchServer(steps=1, duplicate=True) as server:
        with pytest.raises(RunStopped) as stopped:
            _run(synth_root, tmp_path, BATCH_MODEL[provider], api_base=_at(server, provider))
    assert "twice" in str(stopped.value) and "does not choose" in str(stopped.value)
    assert _records(stopped.value.run_dir) == {}


def test_results_of_the_wrong_shape_stop_the_run_with_the_reason_never_a_traceback(tmp_path, synth_root, monkeypatch):
    """A results line that is not an object: the run stops naming the provider's API (it crashed with AttributeError)."""
    from tests.support import fake_batch

    monkeypatch.setattr(fake_batch, "_anthropic_results", lambda server, batch: b'["not an object"]\n')
    with FakeBatchServer(steps=1) as server:
        with pytest.raises(RunStopped) as stopped:
            _run(synth_root, tmp_path, BATCH_MODEL["anthropic"], api_base=server.root)
    first = str(stopped.value).splitlines()[0]
    assert "cannot read the results of batch" in first and "results line 1 is not a JSON object" in first, first
    assert _records(stopped.value.run_dir) == {}


def test_a_results_line_longer_than_one_answer_is_refused_unparsed(monkeypatch):
    """60 MiB of '[{},{},…]' on one line took 2 GB parsed: a line may be one answer (the reply limit) and 1 MiB more."""
    from lightemma.backends import openai_http
    from lightemma.backends.batch.adapter import BatchHTTPError, jsonl_rows

    monkeypatch.setattr(openai_http, "MAX_BODY_BYTES", 1000)
    ok = b'{"custom_id": "a"}\n\n{"custom_id": "b"}\n'
    assert [r["custom_id"] for r in jsonl_rows(ok, "file f")] == ["a", "b"]
    with pytest.raises(BatchHTTPError, match="results line 2 is over 1,049,576 bytes"):
        list(jsonl_rows(b'{"custom_id": "a"}\n[' + b"{}," * 400_000 + b"{}]\n", "file f"))
    with pytest.raises(BatchHTTPError, match="not UTF-8"):
        list(jsonl_rows(b"\xff\xfe", "file f"))


def test_saved_results_that_are_not_a_regular_file_are_polled_again_never_read(tmp_path):
    """A saved results file replaced by a FIFO (a read would block forever) or one past its batch's limit: the journal
    answers "not saved", so the batch is polled again (the provider keeps its results)."""
    journal = BatchJournal.open(tmp_path)
    journal.submitted("tok", "batch_1", ["a", "b"])
    journal.save_results(
        "batch_1", [{"custom_id": "a", "text": "x"}, {"custom_id": "b", "text": "y"}], "completed", 1.0
    )
    saved = tmp_path / journal.batches["batch_1"].results
    assert [i["custom_id"] for i in BatchJournal.open(tmp_path).saved_results("batch_1")] == ["a", "b"]
    saved.unlink()
    os.mkfifo(saved)
    start = time.monotonic()
    assert BatchJournal.open(tmp_path).saved_results("batch_1") is None and time.monotonic() - start < 5
    saved.unlink()
    saved.write_text('{"custom_id": "a"}\n' + " " * (64 << 20) + "\n")  # over 64 MiB for a batch of 2
    assert BatchJournal.open(tmp_path).saved_results("batch_1") is None
    saved.write_text('["a list"]\n')
    assert BatchJournal.open(tmp_path).saved_results("batch_1") is None


@pytest.mark.parametrize("where", ["own", "elsewhere"])
def test_price_is_the_price_of_every_batched_call(tmp_path, synth_root, monkeypatch, where):
    """--price with --batch was dropped: calls were billed at the batch list price (or unknown elsewhere)."""
    if where == "elsewhere":
        monkeypatch.delenv("LIGHTEMMA_PROVIDER_HOSTS", raising=False)
    with FakeBatchServer(steps=1) as server:
        result = _run(synth_root, tmp_path, "openai/gpt-4o", api_base=server.url, sample=2, price=(10.0, 20.0))
    calls = [c for r in _records(result.run_dir).values() for a in r["attempts"] for c in a["calls"]]
    assert len(calls) == 6 and all(c["cost_cents"] == pytest.approx((1000 * 10 + 50 * 20) / 1e6 * 100) for c in calls)
    manifest = json.loads((result.run_dir / "manifest.json").read_text())
    assert "--price 10 20" in manifest["backend"]["cost"]


def _rewrite_openai_results(monkeypatch, change):
    """The OpenAI emulator's results files, each line passed through ``change`` (a JSON line -> its new text)."""
    from tests.support import fake_batch

    real = fake_batch._openai_batch

    def patched(server, batch, input_file, *, peek=False):
        out = real(server, batch, input_file, peek=peek)
        for key in ("output_file_id", "error_file_id"):
            fid = out.get(key)
            if fid and not getattr(batch, "_rewritten_" + key, False):
                lines = [change(json.loads(line)) for line in server.files[fid].decode().splitlines() if line.strip()]
                server.files[fid] = "".join(line + "\n" for line in lines).encode()
                setattr(batch, "_rewritten_" + key, True)
        return out

    monkeypatch.setattr(fake_batch, "_openai_batch", patched)


def _content_list(line):
    line["response"]["body"]["choices"][0]["message"]["content"] = [{"type": "text", "text": "hi"}]
    return json.dumps(line)


def _stranger(line):
    line["custom_id"] = "no-such-request"
    return json.dumps(line)


@pytest.mark.parametrize(
    ("change", "said"),
    [
        (
            lambda line: json.dumps(line).replace('"status_code": 200', '"status_code": 1e999'),
            "status_code inf is no HTTP status",
        ),
        (_content_list, "message content is a list, not text"),
        (_stranger, "'no-such-request', which is no request of this batch"),
    ],
    ids=["status-code-inf", "content-list", "foreign-custom-id"],
)
def test_openai_results_not_as_documented_stop_the_run_in_one_line(tmp_path, synth_root, monkeypatch, change, said):
    """Found by trial: a status_code of 1e999 ended in an OverflowError traceback; a content list was stored as its
    Python text and re-asked; results for no request of the batch had every request re-asked and billed again."""
    _rewrite_openai_results(monkeypatch, change)
    with FakeBatchServer(steps=1) as server:
        with pytest.raises(RunStopped) as stopped:
            _run(synth_root, tmp_path, "openai/gpt-4o", api_base=server.url)
    first = str(stopped.value).splitlines()[0]
    assert "cannot read the results of batch" in first and said in first, first
    assert _records(stopped.value.run_dir) == {} and server.created == 1


@pytest.mark.parametrize("provider", ["openai", "anthropic", "gemini"])
def test_a_batch_state_no_provider_documents_stops_the_run_never_polls_forever(
    tmp_path, synth_root, monkeypatch, provider
):
    from tests.support import fake_batch

    name, key = {
        "openai": ("_openai_batch", "status"),
        "anthropic": ("_anthropic_batch", "processing_status"),
        "gemini": ("_gemini_operation", None),
    }[provider]
    real = getattr(fake_batch, name)

    def banana(*args, **kw):
        out = real(*args, **kw)
        if key:
            out[key] = "banana"
        else:
            out["metadata"]["state"] = "banana"
        return out

    monkeypatch.setattr(fake_batch, name, banana)
    with FakeBatchServer(steps=1) as server:
        with pytest.raises(RunStopped) as stopped:
            _run(synth_root, tmp_path, BATCH_MODEL[provider], api_base=_at(server, provider))
    first = str(stopped.value).splitlines()[0]
    assert "cannot poll batch" in first and "'banana' is none of" in first, first


def test_a_redirect_from_a_batch_api_is_not_followed_nor_read_as_no_results(tmp_path, synth_root, monkeypatch):
    """A 302 on the results file was read as an empty file: every request re-asked and billed again."""
    from tests.support import fake_batch

    real = fake_batch._anthropic_results
    monkeypatch.setattr(fake_batch, "_anthropic_results", lambda server, batch: real(server, batch))
    with FakeBatchServer(steps=1) as server:
        original = server._handler()

        class Redirecting(original):
            def do_GET(self):  # noqa: N802
                if self.path.endswith("/results"):
                    self.send_response(302)
                    self.send_header("Location", "http://127.0.0.1:9/elsewhere")
                    self.send_header("Content-Length", "0")
                    self.end_headers()
                    return
                super().do_GET()

        server._server.RequestHandlerClass = Redirecting
        with pytest.raises(RunStopped) as stopped:
            _run(synth_root, tmp_path, BATCH_MODEL["anthropic"], api_base=server.root)
    first = str(stopped.value).splitlines()[0]
    assert "HTTP 302" in first and "follows no redirect" in first and "127.0.0.1:9/elsewhere" in first, first


def test_each_batch_call_has_the_whole_timeout_and_a_trickle_is_cut_off(tmp_path):
    """httpx bounds each read, not a call: a reply trickled byte by byte was waited on without end."""
    import asyncio

    from lightemma.backends.batch import BatchBackend
    from lightemma.backends.retry import RetryPolicy
    from lightemma.errors import RunFatalError

    class Trickle:
        provider = "openai"

        async def status(self, batch_id):
            await asyncio.sleep(60)

    backend = BatchBackend(
        "openai/gpt-4o",
        api_base="http://127.0.0.1:9/v1",
        timeout=0.3,
        adapter=Trickle(),
        retry=RetryPolicy(max_retries=1, base=0.01, cap=0.02),
    )
    start = time.monotonic()
    with pytest.raises(RunFatalError) as fatal:
        asyncio.run(backend._call(lambda: backend.adapter.status("b"), "poll batch b", requests=4))
    assert time.monotonic() - start < 5
    assert (
        fatal.value.error == "Timeout"
        and "within --timeout 0.3 s" in str(fatal.value)
        and "after 1 retries" in str(fatal.value)
    )


def test_an_answer_over_the_reply_limit_is_that_requests_error_not_a_record(monkeypatch):
    """One 60 MiB answer took 4 GB and a 943 MB frames.jsonl line no reader reads: a batch answer gets the online
    reply limit."""
    from lightemma.backends import openai_http
    from lightemma.backends.batch.adapter import checked_results

    monkeypatch.setattr(openai_http, "MAX_BODY_BYTES", 1000)
    items = checked_results([{"custom_id": "a", "text": "ok"}, {"custom_id": "b", "text": "é" * 600}], ["a", "b"])
    assert items[0]["text"] == "ok" and items[1]["text"] is None
    assert items[1]["error"] == "ResponseTooLargeError" and "over 1,000 bytes" in items[1]["error_message"]


def test_provider_ids_stay_one_piece_of_the_url():
    from lightemma.backends.batch.adapter import BatchHTTPError, url_id

    assert url_id("../../../x?y#z") == "..%2F..%2F..%2Fx%3Fy%23z"
    assert url_id("batches/abc-123", slash=True) == "batches/abc-123"
    with pytest.raises(BatchHTTPError):
        url_id("batches/../../x", slash=True)


def test_saved_results_holding_a_request_twice_or_a_link_are_polled_again(tmp_path):
    journal = BatchJournal.open(tmp_path)
    journal.submitted("tok", "batch_1", ["a", "b"])
    journal.save_results(
        "batch_1", [{"custom_id": "a", "text": "x"}, {"custom_id": "b", "text": "y"}], "completed", 1.0
    )
    saved = tmp_path / journal.batches["batch_1"].results
    with saved.open("a") as fh:
        fh.write(json.dumps({"custom_id": "a", "text": "x", "input_tokens": 999999}) + "\n")
    assert BatchJournal.open(tmp_path).saved_results("batch_1") is None  # was: the last copy, 626 ¢
    saved.unlink()
    saved.symlink_to("/dev/zero")
    assert (
        BatchJournal.open(tmp_path).saved_results("batch_1") is None
    )  # was: "names results outside the run directory"


def test_the_basic_auth_value_a_server_echoes_is_kept_out_of_messages_and_files(tmp_path, synth_root):
    with FakeBatchServer(steps=1) as server:
        base = server.url.replace("http://", "http://alice:s3cr3tPW@")
        basic = "Basic " + base64.b64encode(b"alice:s3cr3tPW").decode()
        server.require_key, server.refusal = "a-key-never-sent", f"bad key: {basic}"
        with pytest.raises(RunStopped) as stopped:
            _run(synth_root, tmp_path, "openai/gpt-4o", api_base=base, sample=2)
    token = basic.split(" ", 1)[1]
    written = b"".join(p.read_bytes() for p in (tmp_path / "runs").rglob("*") if p.is_file())
    assert "bad key" in str(stopped.value) and token not in str(stopped.value)
    assert token.encode() not in written and b"s3cr3tPW" not in written
