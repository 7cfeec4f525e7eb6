"""Issue 33: every way a ``--batch`` run paid twice or could never finish, played by the loopback batch server
(tests/support/fake_batch.py) with the fault injected — and in every case, 0 requests billed twice
(:meth:`fake_batch.FakeBatchServer.paid_twice`: per request, the batches that ran it; per custom id, the batches
it went into).
"""

from __future__ import annotations

import json
import os
import threading
from pathlib import Path

import pytest

import lightemma.backends.batch as batch_module
from lightemma.backends.batch import journal as journal_module
from lightemma.backends.batch.journal import BatchJournal
from lightemma.errors import RunStopped, RunStoreError
from lightemma.pipeline.runner import resume, run
from lightemma.runs.store import read_run
from tests.support.fake_batch import FakeBatchServer

MODELS = {"openai": "openai/gpt-4o", "anthropic": "anthropic/claude-sonnet-4-6", "gemini": "gemini/gemini-2.5-flash"}
BASES = {"anthropic": "ANTHROPIC_API_BASE", "gemini": "GEMINI_API_BASE"}


@pytest.fixture(autouse=True)
def _fast(monkeypatch):
    monkeypatch.setattr(batch_module, "IDLE_SECONDS", 0.15)
    monkeypatch.setenv("OPENAI_API_KEY", "sk-test-openai")
    monkeypatch.setenv("ANTHROPIC_API_KEY", "sk-ant-test")
    monkeypatch.setenv("GEMINI_API_KEY", "gm-test-key")


def _where(server, provider, monkeypatch):
    """The run's endpoint: OpenAI's --api-base, the others' base variable (their own host, declared)."""
    if provider == "openai":
        return {"api_base": server.url}
    monkeypatch.setenv(BASES[provider], server.root)
    return {}


def _run(synth_root, tmp_path, provider, server, monkeypatch, **kw):
    kw.setdefault("sample", 4)
    return run(
        MODELS[provider],
        dataroot=synth_root,
        version="v1.0-mini",
        split="all",
        output=tmp_path / "runs",
        batch=True,
        batch_poll=0.01,
        progress=False,
        **_where(server, provider, monkeypatch),
        **kw,
    )


def _resume(run_dir, server, provider, **kw):
    return resume(run_dir, progress=False, api_base=server.url if provider == "openai" else None, **kw)


def _stopped_run(synth_root, tmp_path, provider, server, monkeypatch, cause, **kw):
    with pytest.raises(RunStopped) as stopped:
        _run(synth_root, tmp_path, provider, server, monkeypatch, **kw)
    assert stopped.value.cause == cause, str(stopped.value)
    assert "\n" not in str(stopped.value) and "--resume" in str(stopped.value)
    return stopped.value


def _all_ok(run_dir, n=4):
    records = read_run(run_dir).records
    assert len(records) == n and all(r["status"] == "ok" for r in records.values())
    return records


def _events(run_dir):
    return [json.loads(line) for line in (Path(run_dir) / "batches.jsonl").read_text().split("\n") if line]


# -- 1. a lost answer to "create batch" ---------------------------------------------------------------------------


@pytest.mark.parametrize("provider", ["openai", "gemini"])
def test_a_create_whose_answer_is_lost_is_looked_up_not_created_again(tmp_path, synth_root, monkeypatch, provider):
    with FakeBatchServer(steps=1, lose_create=1) as server:  # the provider creates the batch, then answers 500
        result = _run(synth_root, tmp_path, provider, server, monkeypatch)
    _all_ok(result.run_dir)
    assert server.created == 3 and server.paid_twice() == []
    assert server.list_calls >= 1  # it was looked up by its token


def test_a_create_cut_off_by_the_timeout_is_looked_up_not_created_again(tmp_path, synth_root, monkeypatch):
    with FakeBatchServer(steps=1, lose_create=1, create_delay=2.5) as server:  # answered after --timeout
        result = _run(synth_root, tmp_path, "openai", server, monkeypatch, timeout=1.0)
    _all_ok(result.run_dir)
    assert server.created == 3 and server.paid_twice() == []


@pytest.mark.parametrize("provider", ["openai", "anthropic", "gemini"])
def test_a_create_refused_with_a_server_error_is_created_once_it_is_known_not_to_exist(
    tmp_path, synth_root, monkeypatch, provider
):
    with FakeBatchServer(steps=1, fail_create=1) as server:  # 503, nothing created: the look-up finds none
        result = _run(synth_root, tmp_path, provider, server, monkeypatch)
    _all_ok(result.run_dir)
    assert server.created == 3 and server.paid_twice() == []


def test_an_anthropic_create_whose_answer_is_lost_stops_rather_than_create_it_again(tmp_path, synth_root, monkeypatch):
    """Anthropic batches have no name to look up: a batch of the same size created since is not created again."""
    with FakeBatchServer(steps=1, lose_create=1) as server:
        stop = _stopped_run(synth_root, tmp_path, "anthropic", server, monkeypatch, "batch-unconfirmed")
    assert "msgbatch_0001" in str(stop) and "console" in str(stop)
    assert server.created == 1 and server.paid_twice() == []


# -- 2. the look-up reads every page, down to the submission --------------------------------------------------------


class Killed(BaseException):
    """The process dying at that point (a BaseException: nothing in lightemma catches it, as with SIGKILL)."""


def _killed_before_the_id_is_journaled(monkeypatch):
    calls = {"n": 0}
    original = BatchJournal.submitted

    def killed_once(self, token, batch_id, custom_ids):
        calls["n"] += 1
        if calls["n"] == 1:
            raise Killed  # the process dies right after the provider created the batch
        return original(self, token, batch_id, custom_ids)

    monkeypatch.setattr(BatchJournal, "submitted", killed_once)


@pytest.mark.parametrize("provider", ["openai", "gemini"])
def test_an_interrupted_submission_is_found_behind_150_newer_batches(tmp_path, synth_root, monkeypatch, provider):
    _killed_before_the_id_is_journaled(monkeypatch)
    with FakeBatchServer(steps=1, page_size=100) as server:
        with pytest.raises(Killed):
            _run(synth_root, tmp_path, provider, server, monkeypatch)
        run_dir = next((tmp_path / "runs").glob("*/*"))
        server.add_foreign(150, provider)  # the account's other batches, all newer than the run's
        _resume(run_dir, server, provider)
    _all_ok(run_dir)
    assert server.created == 3 and server.paid_twice() == []
    assert server.list_calls >= 2  # more than the first page was read


def test_an_anthropic_submission_cut_off_before_the_create_is_made_once_all_pages_show_none(
    tmp_path, synth_root, monkeypatch
):
    calls = {"n": 0}
    from lightemma.backends.batch.anthropic import AnthropicBatches

    original = AnthropicBatches.submit

    async def killed_once(self, entries, token):
        calls["n"] += 1
        if calls["n"] == 1:
            raise Killed  # killed after the 'submitting' line, before the provider was asked
        return await original(self, entries, token)

    monkeypatch.setattr(AnthropicBatches, "submit", killed_once)
    with FakeBatchServer(steps=1, page_size=100) as server:
        with pytest.raises(Killed):
            _run(synth_root, tmp_path, "anthropic", server, monkeypatch)
        run_dir = next((tmp_path / "runs").glob("*/*"))
        server.add_foreign(150, "anthropic", size=1)  # newer batches of another size: not this submission
        _resume(run_dir, server, "anthropic")
    _all_ok(run_dir)
    assert server.created == 3 and server.paid_twice() == [] and server.list_calls >= 2
    assert [e["event"] for e in _events(run_dir)][:2] == ["submitting", "abandoned"]


# -- 3. a journal write that does not reach the disk ---------------------------------------------------------------


def _disk_full_on(monkeypatch, event, times=1):
    """os.write of the batch journal writes half the line (then nothing) for the next ``times`` ``event`` lines."""
    real = os.write
    left = {"n": times}

    def write(fd, data):
        try:
            journal = os.readlink(f"/proc/self/fd/{fd}").endswith("batches.jsonl")
        except OSError:
            journal = False
        if journal and f'"event":"{event}"'.encode() in data and left["n"] > 0:
            left["n"] -= 1
            return real(fd, data[: len(data) // 2])  # a short write: the disk filled up
        return real(fd, data)

    monkeypatch.setattr(journal_module.os, "write", write)


def test_a_short_journal_write_creates_no_batch_and_the_resume_goes_on(tmp_path, synth_root, monkeypatch):
    _disk_full_on(monkeypatch, "submitting")
    with FakeBatchServer(steps=1) as server:
        stop = _stopped_run(synth_root, tmp_path, "openai", server, monkeypatch, "disk")
        assert "batch journal" in str(stop) and server.created == 0  # nothing created after the line that failed
        run_dir = stop.run_dir
        assert (run_dir / "batches.jsonl").read_bytes() in (b"",)  # the half line was cut back off
        monkeypatch.undo()
        monkeypatch.setattr(batch_module, "IDLE_SECONDS", 0.15)
        monkeypatch.setenv("OPENAI_API_KEY", "sk-test-openai")
        _resume(run_dir, server, "openai")
    _all_ok(run_dir)
    assert server.created == 3 and server.paid_twice() == []


def test_a_short_write_of_the_batch_id_is_found_by_its_token_on_resume(tmp_path, synth_root, monkeypatch):
    _disk_full_on(monkeypatch, "submitted")
    with FakeBatchServer(steps=1) as server:
        stop = _stopped_run(synth_root, tmp_path, "openai", server, monkeypatch, "disk")
        assert server.created == 1
        monkeypatch.undo()
        monkeypatch.setattr(batch_module, "IDLE_SECONDS", 0.15)
        monkeypatch.setenv("OPENAI_API_KEY", "sk-test-openai")
        _resume(stop.run_dir, server, "openai")
        _resume(stop.run_dir, server, "openai")  # and every later resume reads the journal
    _all_ok(stop.run_dir)
    assert server.created == 3 and server.paid_twice() == []


def test_a_resume_repairs_a_torn_last_line_instead_of_refusing_the_journal(tmp_path):
    journal = BatchJournal.open(tmp_path)
    journal.submitting("t1", ["a", "b"])
    journal.submitted("t1", "batch_1", ["a", "b"])
    with open(journal.path, "ab") as fh:
        fh.write(b'{"event":"submitting","tok')  # killed mid-write
    again = BatchJournal.open(tmp_path, repair=True)  # a session: the torn line is cut off
    assert journal.path.read_bytes().endswith(b"}\n")
    again.submitting("t2", ["c"])
    after = BatchJournal.open(tmp_path)  # not "damaged"
    assert after.by_custom_id == {"a": "batch_1", "b": "batch_1"} and list(after.unconfirmed) == ["t2"]


# -- 6. a batch failed as a whole; a results line holding U+2028 -------------------------------------------------


def test_a_batch_failed_at_the_enqueued_token_limit_is_resubmitted(tmp_path, synth_root, monkeypatch):
    with FakeBatchServer(steps=1, fail_batches={1}, fail_code="token_limit_exceeded") as server:
        result = _run(synth_root, tmp_path, "openai", server, monkeypatch)
    _all_ok(result.run_dir)
    assert server.created == 4 and server.paid_twice() == []
    assert [e["event"] for e in _events(result.run_dir)][:4] == ["submitting", "submitted", "failed", "submitting"]


def test_a_batch_rejected_as_a_whole_is_submitted_again_by_the_resume_not_polled_forever(
    tmp_path, synth_root, monkeypatch
):
    with FakeBatchServer(steps=1, batch_state="failed") as server:
        stop = _stopped_run(synth_root, tmp_path, "openai", server, monkeypatch, "batch-failed")
        assert "line 1: bad model" in str(stop) and server.created == 1
        server.batch_state = None  # the user fixed what it named
        _resume(stop.run_dir, server, "openai")
    _all_ok(stop.run_dir)
    assert server.created == 4 and server.paid_twice() == []


@pytest.mark.parametrize("provider", ["openai", "anthropic", "gemini"])
def test_a_results_line_holding_u2028_or_u0085_is_one_line_of_json(tmp_path, synth_root, monkeypatch, provider):
    from tests.support.fake_openai import Reply, default_reply

    def script(received):
        reply = default_reply(received)
        if received.stage == "scene":
            reply.content = "A two-lane road\u2028with a cyclist\u0085ahead."
        return reply

    with FakeBatchServer(script, steps=1, raw_text=True) as server:
        result = _run(synth_root, tmp_path, provider, server, monkeypatch, sample=2)
    records = _all_ok(result.run_dir, 2)
    assert all(
        r["attempts"][0]["calls"][0]["text"] == "A two-lane road\u2028with a cyclist\u0085ahead."
        for r in records.values()
    )
    assert server.paid_twice() == [] and isinstance(Reply, type)


# -- 7. batches.jsonl read like every run file ------------------------------------------------------------------------


def test_a_fifo_journal_is_refused_at_once_not_waited_on(tmp_path):
    os.mkfifo(tmp_path / "batches.jsonl")
    done = threading.Event()
    caught = {}

    def read():
        try:
            BatchJournal.open(tmp_path)
        except RunStoreError as exc:
            caught["error"] = str(exc)
        done.set()

    threading.Thread(target=read, daemon=True).start()
    assert done.wait(30), "the journal read hung on a FIFO"
    assert "not a regular file" in caught["error"]


def test_a_journal_linked_to_dev_zero_or_too_large_is_refused_in_one_line(tmp_path, monkeypatch):
    (tmp_path / "batches.jsonl").symlink_to("/dev/zero")
    with pytest.raises(RunStoreError, match="link"):
        BatchJournal.open(tmp_path)
    (tmp_path / "batches.jsonl").unlink()
    (tmp_path / "batches.jsonl").write_text('{"event":"abandoned","token":"t"}\n' * 40)
    monkeypatch.setattr(journal_module, "MAX_JOURNAL_BYTES", 1000)
    with pytest.raises(RunStoreError, match="over the 1,000"):
        BatchJournal.open(tmp_path)


@pytest.mark.parametrize(
    "line, said",
    [
        ('{"event":"submitted","token":"t","custom_ids":["a"]}', "batch_id is NoneType"),
        ('{"event":"submitted","token":"t","batch_id":"b","custom_ids":5}', "custom_ids is not a list"),
        ('{"event":"submitting","token":["t"],"custom_ids":[]}', "token is list"),
        ('{"event":"completed","batch_id":"nope","state":"completed","results":"x"}', "never submitted"),
        ('{"event":"submitting","token":"t","custom_ids":[],"at":"yesterday"}', "not a time"),
        ("[" * 3000 + "]" * 3000, "not a JSON line"),
        ('{"event":"submitting","token":"t","custom_ids":[],"at":1' + "0" * 5000 + "}", "not a JSON line"),
        ("7", "not a batch journal event"),
    ],
)
def test_a_hand_edited_journal_line_is_one_line_naming_it(tmp_path, line, said):
    (tmp_path / "batches.jsonl").write_text(
        '{"event":"submitting","token":"t0","custom_ids":["z"],"at":1}\n' + line + "\n"
    )
    with pytest.raises(RunStoreError) as error:
        BatchJournal.open(tmp_path)
    message = str(error.value)
    assert said in message and "batches.jsonl:2" in message and "\n" not in message and len(message) < 400


# -- 5. a cancel in the provider's console; the resubmission limit across attempts ------------------------------------


@pytest.mark.parametrize("provider", ["openai", "anthropic", "gemini"])
def test_a_canceled_batch_stops_the_run_and_the_resume_submits_it_again(tmp_path, synth_root, monkeypatch, provider):
    with FakeBatchServer(steps=1, cancel={1}) as server:
        stop = _stopped_run(synth_root, tmp_path, provider, server, monkeypatch, "batch-canceled")
        assert "canceled" in str(stop) and server.created == 1  # the cancel is not undone by resubmitting
        _resume(stop.run_dir, server, provider)
    _all_ok(stop.run_dir)
    assert server.created == 4 and server.paid_twice() == []


def test_the_resubmission_limit_holds_across_attempts(tmp_path, synth_root, monkeypatch):
    from tests.support.fake_openai import Received

    stuck_body: dict[str, str] = {}

    def never_run(cid, body):  # the first stage-2 request's frame is never reached by any batch, in any attempt
        if Received(path="/v1/chat/completions", headers={}, body=body, index=0).stage != "intent":
            return False
        key = json.dumps(body["messages"][0], sort_keys=True)
        return stuck_body.setdefault("key", key) == key

    with FakeBatchServer(steps=1, unrun=never_run) as server:
        result = _run(synth_root, tmp_path, "openai", server, monkeypatch, sample=2)
    records = read_run(result.run_dir).records
    failed = [r for r in records.values() if r["status"] != "ok"]
    assert failed and all(r["n_attempts"] > 1 for r in failed)  # the chain re-asked it in later attempts
    stuck = [cid for b in server.batches.values() for cid, body in b.requests if never_run(cid, body)]
    resubmitted = [cid for cid in stuck if "-r" in cid]
    # twice at most per frame and stage, whatever the attempt (each attempt once had two of its own)
    assert len(resubmitted) == 2 * len(failed)
    assert server.paid_twice() == []


# -- 4. empty or partial results ----------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "provider, fault",
    [
        ("openai", "empty"),
        ("openai", "no_file"),
        ("openai", "half"),
        ("anthropic", "empty"),
        ("anthropic", "half"),
        ("gemini", "no_file"),
        ("gemini", "half"),
    ],
)
def test_results_short_of_the_providers_counts_stop_the_run_and_are_read_again_never_reasked(
    tmp_path, synth_root, monkeypatch, provider, fault
):
    with FakeBatchServer(steps=1, results_fault=fault) as server:
        stop = _stopped_run(synth_root, tmp_path, provider, server, monkeypatch, "batch-results")
        assert "incomplete" in str(stop) and server.created == 1  # nothing asked again
        assert "completed" not in [e["event"] for e in _events(stop.run_dir)]  # nothing saved as final
        server.results_fault = None  # the provider's results readable again
        _resume(stop.run_dir, server, provider)
    _all_ok(stop.run_dir)
    assert server.created == 3 and server.paid_twice() == []


@pytest.mark.parametrize("provider", ["openai", "anthropic", "gemini"])
def test_results_short_once_are_read_again_and_the_run_goes_on(tmp_path, synth_root, monkeypatch, provider):
    with FakeBatchServer(steps=1, results_fault="half", fault_reads=1) as server:
        result = _run(synth_root, tmp_path, provider, server, monkeypatch)
    _all_ok(result.run_dir)
    assert server.created == 3 and server.paid_twice() == []


def test_gemini_results_in_a_responses_file_are_read(tmp_path, synth_root, monkeypatch):
    with FakeBatchServer(steps=1, results_fault="responses_file") as server:
        result = _run(synth_root, tmp_path, "gemini", server, monkeypatch)
    _all_ok(result.run_dir)
    assert server.created == 3 and server.paid_twice() == []


# -- 9. --max-cost in batch mode ---------------------------------------------------------------------------------------


def test_max_cost_checks_each_finished_waves_reported_cost_before_sending_the_next(tmp_path, synth_root, monkeypatch):
    """The provider bills 20,000 input tokens per call where the estimate said about a thousand: the first wave is
    admitted at the estimate, its reported cost shows the limit would pass, and no further wave is sent."""
    import lightemma
    from lightemma.pipeline.runner import estimate_run
    from tests.support.fake_openai import default_reply

    def costly(received):
        reply = default_reply(received)
        reply.prompt_tokens = 20_000
        return reply

    from lightemma.runs.store import read_frame_ids

    with FakeBatchServer(steps=1) as probe_server:
        probe = _run(synth_root, tmp_path / "probe", "openai", probe_server, monkeypatch)
    frames = lightemma.load_frames(synth_root, "v1.0-mini", split="all").select(read_frame_ids(probe.run_dir))
    per_frame = estimate_run("openai/gpt-4o", frames=frames).batch_cost_cents / 4
    limit = 3.5 * per_frame
    with FakeBatchServer(costly, steps=1) as server:
        stop = _stopped_run(synth_root, tmp_path, "openai", server, monkeypatch, "budget", max_cost_cents=limit)
    assert "--max-cost" in str(stop)
    assert server.created == 1  # the first wave only: stages 2 and 3 were never sent (once all three went out)
    spent = sum(len(b.requests) for b in server.batches.values()) * (20_000 * 1.25 + 50 * 5.0) / 1e6 * 100
    wave = len(next(iter(server.batches.values())).requests) * (20_000 * 1.25 + 50 * 5.0) / 1e6 * 100
    assert spent <= limit + wave  # within one wave's worth of the limit
    assert server.paid_twice() == []
