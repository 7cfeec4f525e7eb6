"""Runs that stop when they cannot succeed, never outlive their timeout, and record only what is true.

Each case drives `lightemma run` (in process, through the CLI's own entry point) against the scripted
loopback server and checks: the exit code, the number of calls the server saw (bounded: a stop comes
within about two waves of `--concurrency` calls), the one error line, and that what finished is intact
and that `--resume` finishes the run once the cause is fixed.
"""

import asyncio
import base64
import errno
import json
import os
import socket
import subprocess
import sys
import threading
import time
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

import lightemma
import lightemma.synth
from lightemma.backends import ChatRequest, GenerationParams, create_backend
from lightemma.backends.batching import MicroBatcher
from lightemma.backends.retry import FailureStreak, RetryPolicy, failure_signature
from lightemma.cli import main as cli_main
from lightemma.errors import RunFatalError, RunStopped, RunStoreError
from lightemma.pipeline import resume, run
from lightemma.runs import store
from lightemma.runs.store import FRAMES_FILE, RunLock, read_manifest, read_run
from tests.support.fake_openai import GOOD_ACTIONS, SCENE_TEXT, FakeOpenAIServer, Reply, default_reply
from tests.support.memframes import FrameIndex, make_frames

CONCURRENCY = 4
N_FRAMES = 12  # the synthetic dataset of conftest: 2 scenes × 20 keyframes


@pytest.fixture(autouse=True)
def _no_debug(monkeypatch):
    monkeypatch.delenv("LIGHTEMMA_DEBUG", raising=False)


class Switch:
    """A server script that gives ``bad`` (a Reply, or a function of the request) until ``fixed`` is set."""

    def __init__(self, bad):
        self.bad = bad
        self.fixed = False
        self.broken_calls = 0
        self._lock = threading.Lock()

    def __call__(self, req):
        if self.fixed:
            return default_reply(req)
        with self._lock:
            self.broken_calls += 1
        return self.bad(req) if callable(self.bad) else self.bad


def run_cli(capsys, *args):
    """``lightemma run ARGS`` in process: (exit code, stdout, the stderr lines that carry an error)."""
    code = cli_main(["run", *map(str, args)])
    out, err = capsys.readouterr()
    assert "Traceback" not in err, err
    return code, out, [line for line in err.splitlines() if "error:" in line]


def start(capsys, server, synth_root, out, *extra, transport="litellm"):
    return run_cli(
        capsys,
        "--model",
        "openai/test-model",
        "--api-base",
        server.url,
        "--dataroot",
        synth_root,
        "--version",
        "v1.0-mini",
        "--split",
        "all",
        "--concurrency",
        CONCURRENCY,
        "--output",
        out,
        "--backoff",
        0.01,
        "--max-retries",
        1,
        "--timeout",
        5,
        "--transport",
        transport,
        "--no-progress",
        *extra,
    )


def only_run_dir(out):
    (run_dir,) = store.find_run_dirs(out)
    return run_dir


def assert_resumes_to_the_end(capsys, run_dir, switch):
    """After the fix, --resume finishes the run: every frame exactly once, all ok, the stop kept in the manifest."""
    before = read_run(run_dir)
    assert not before.complete and not before.truncated_tail and not before.corrupt_lines
    switch.fixed = True
    endpoint = read_manifest(run_dir)["config"]["api_base"]  # the user names the run's endpoint again
    code, out, errors = run_cli(capsys, "--resume", run_dir, "--api-base", endpoint, "--no-progress")
    assert code == 0 and not errors, errors
    after = read_run(run_dir)
    # frames that ended failed with the error that stopped the run are redone: one fresh record each (the last wins)
    redone = Counter(fid for fid, r in before.records.items() if r["status"] == "failed")
    assert after.complete and len(after.records) == N_FRAMES and after.duplicates == sum(redone.values())
    assert (
        Counter(json.loads(line)["frame_id"] for line in (run_dir / FRAMES_FILE).read_text().splitlines())
        == Counter(set(after.records)) + redone
    )
    assert all(r["status"] == "ok" for r in after.records.values())
    sessions = read_manifest(run_dir)["sessions"]
    assert (
        [s["kind"] for s in sessions] == ["run", "resume"] and "stopped" in sessions[0] and "stopped" not in sessions[1]
    )
    return sessions[0]["stopped"]


# -- run-fatal causes ---------------------------------------------------------------------------------------


WORDINGS = {
    "usual": "Incorrect API key provided: sk-wrong-0123456789. You can find your API key at https://platform.openai.com",
    "other": "You didn't provide an API key. You need to provide your API key in an Authorization header",
}


@pytest.mark.parametrize("transport", ["litellm", "direct"])
@pytest.mark.parametrize("wording", list(WORDINGS))
def test_a_rejected_key_in_either_wording_stops_the_run_at_once_and_resume_finishes_it(
    tmp_path, synth_root, capsys, wording, transport
):
    body = {"error": {"message": WORDINGS[wording], "type": "invalid_request_error", "code": None}}
    switch = Switch(Reply(status=401, body=body))
    with FakeOpenAIServer(switch) as server:
        code, _, errors = start(capsys, server, synth_root, tmp_path, transport=transport)
        assert code == 2 and len(errors) == 1, errors
        assert (
            "AuthenticationError" in errors[0] and "API key was rejected" in errors[0] and "OPENAI_API_KEY" in errors[0]
        )
        assert "sk-wrong" not in errors[0] and "lightemma run --resume" in errors[0]
        assert len(server.requests) <= CONCURRENCY  # the first 401 stops everything: only the first wave was sent
        stopped = assert_resumes_to_the_end(capsys, only_run_dir(tmp_path), switch)
    assert (stopped["cause"], stopped["error"]) == ("authentication", "AuthenticationError")


@pytest.mark.parametrize("transport", ["litellm", "direct"])
def test_the_same_invalid_request_on_every_frame_stops_the_run(tmp_path, synth_root, capsys, transport):
    switch = Switch(Reply.error(400, "Invalid image: image is too large (4312 x 9001 px)"))
    with FakeOpenAIServer(switch) as server:
        code, _, errors = start(capsys, server, synth_root, tmp_path, transport=transport)
        assert code == 2 and len(errors) == 1, errors
        assert "BadRequestError" in errors[0] and "image is too large" in errors[0] and "frames in a row" in errors[0]
        # an image rejection may be tied to one scene's frames: it stops the run once it spans the second scene
        assert len(server.requests) <= 5 * (N_FRAMES // 2 + CONCURRENCY)
        stopped = assert_resumes_to_the_end(capsys, only_run_dir(tmp_path), switch)
    assert stopped["cause"] == "invalid-request"


def test_one_frame_whose_request_is_always_rejected_fails_alone(tmp_path):
    """A deterministic 400 for one frame's image is that frame's failure; the others keep the run going."""
    frames = make_frames(tmp_path, 8)
    bad = frames[3].image_path

    bad_data = base64.b64encode(open(bad, "rb").read()).decode()

    def script(req):
        url = next(p["image_url"]["url"] for p in req.body["messages"][-1]["content"] if p["type"] == "image_url")
        mine = url.endswith(bad_data)
        return Reply.error(400, "Invalid image content") if mine else default_reply(req)

    with FakeOpenAIServer(script) as server:
        result = run(
            "openai/test-model",
            api_base=server.url,
            frames=frames,
            output=tmp_path,
            concurrency=1,
            max_attempts=3,
            backoff_base=0.01,
            progress=False,
        )
    records = read_run(result.run_dir).records
    assert records[frames[3].frame_id]["status"] == "failed" and records[frames[3].frame_id]["n_attempts"] == 3
    assert sum(r["status"] == "ok" for r in records.values()) == 7


def test_a_reasoning_budget_spent_without_an_answer_stops_the_run_with_the_max_tokens_fix(tmp_path, synth_root, capsys):
    switch = Switch(Reply(content="", finish_reason="length", completion_tokens=512, reasoning_tokens=512))
    with FakeOpenAIServer(switch) as server:
        code, _, errors = start(capsys, server, synth_root, tmp_path)
        assert code == 2 and len(errors) == 1, errors
        assert "spent its whole output budget" in errors[0] and "raise --max-tokens" in errors[0]
        assert len(server.requests) <= 2 * CONCURRENCY
        stopped = assert_resumes_to_the_end(capsys, only_run_dir(tmp_path), switch)
    assert (stopped["cause"], stopped["error"]) == ("reasoning-budget", "EmptyResponse")


def test_a_dead_api_base_stops_the_run(tmp_path, synth_root, capsys):
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]  # closed again: nothing listens there
    code, _, errors = run_cli(
        capsys,
        "--model",
        "openai/test-model",
        "--api-base",
        f"http://127.0.0.1:{port}/v1",
        "--dataroot",
        synth_root,
        "--version",
        "v1.0-mini",
        "--split",
        "all",
        "--concurrency",
        CONCURRENCY,
        "--output",
        tmp_path,
        "--backoff",
        0.01,
        "--max-retries",
        0,
        "--no-progress",
    )
    assert code == 2 and len(errors) == 1 and "cannot connect" in errors[0] and "--api-base" in errors[0], errors
    assert not list(Path(tmp_path).iterdir())  # refused before any work: no run directory


def test_a_typo_in_the_model_name_is_one_line_before_any_work(tmp_path, synth_root, capsys, monkeypatch):
    monkeypatch.setenv("OPENAI_API_KEY", "sk-test-0123456789")
    code, _, errors = run_cli(
        capsys,
        "--model",
        "gtp-4o",
        "--dataroot",
        synth_root,
        "--version",
        "v1.0-mini",
        "--split",
        "all",
        "--output",
        tmp_path / "out",
    )
    assert code == 2 and len(errors) == 1, errors
    assert (
        "unknown model 'gtp-4o'" in errors[0] and "did you mean gpt-4o" in errors[0] and "lightemma models" in errors[0]
    )
    assert not (tmp_path / "out").exists()


# -- deadlines ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("transport", ["litellm", "direct"])
def test_a_trickling_server_is_cut_off_at_the_deadline(transport):
    """One byte every 0.25 s never trips a read timeout; lightemma's deadline bounds the whole call."""
    with FakeOpenAIServer(lambda req: Reply(SCENE_TEXT, trickle=0.25)) as server:
        backend = create_backend(
            "openai/test-model",
            api_base=server.url,
            timeout=1.0,
            transport=transport,
            retry=RetryPolicy(max_retries=1, base=0.01, cap=0.02),
        )
        request = ChatRequest(text="describe", stage="scene", frame_id="f")
        began = time.perf_counter()
        result = asyncio.run(backend.generate([request]))[0]
        elapsed = time.perf_counter() - began
    assert (result.error, result.retries, len(server.requests)) == ("Timeout", 1, 2)
    assert "connect to last byte" in result.error_message
    assert 2.0 <= elapsed < 6.0  # two attempts of 1 s each (and a loaded machine's overhead), not 2 × ~90 s of trickle


def test_a_server_that_trickles_every_answer_stops_the_run_within_its_deadlines(tmp_path, synth_root, capsys):
    switch = Switch(lambda req: Reply(SCENE_TEXT, trickle=0.2))
    with FakeOpenAIServer(switch) as server:
        began = time.perf_counter()
        code, _, errors = run_cli(
            capsys,
            "--model",
            "openai/test-model",
            "--api-base",
            server.url,
            "--dataroot",
            synth_root,
            "--version",
            "v1.0-mini",
            "--split",
            "all",
            "--concurrency",
            CONCURRENCY,
            "--output",
            tmp_path,
            "--max-retries",
            0,
            "--timeout",
            0.6,
            "--no-progress",
        )
        elapsed = time.perf_counter() - began
        assert (
            code == 2 and len(errors) == 1 and "Timeout" in errors[0] and "raise --timeout (now 0.6 s)" in errors[0]
        ), errors
        assert len(server.requests) <= 2 * CONCURRENCY and elapsed < 20
        run_dir = only_run_dir(tmp_path)
        assert read_run(run_dir).records == {}


# -- untrue figures -----------------------------------------------------------------------------------------


@pytest.mark.parametrize("transport", ["litellm", "direct"])
def test_a_reply_without_usage_is_unknown_tokens_and_cost_never_zero(tmp_path, transport):
    frames = make_frames(tmp_path, 4)
    with FakeOpenAIServer(lambda req: Reply(default_reply(req).content, usage=False)) as server:
        result = run(
            "openai/gpt-4o",
            api_base=server.url,
            frames=frames,
            output=tmp_path,
            transport=transport,
            backoff_base=0.01,
            progress=False,
        )
    for record in read_run(result.run_dir).records.values():
        assert record["status"] == "ok"
        assert (record["input_tokens"], record["output_tokens"], record["cost_cents"]) == (None, None, None)
        assert all(
            c["input_tokens"] is None and c["cost_cents"] is None for a in record["attempts"] for c in a["calls"]
        )
    summary = result.summary
    assert summary["frames_tokens_unknown"] == 4 and summary["mean_input_tokens"] is None
    assert summary["total_cost_cents"] is None and summary["frames_cost_unknown"] == 4
    assert "(4 unknown)" in result.report()


def test_the_litellm_transport_keeps_the_tpm_reservation_of_a_call_without_usage():
    from lightemma.backends.api import ESTIMATED_TOKENS_PER_CALL

    with FakeOpenAIServer(lambda req: Reply("a street", usage=False)) as server:
        backend = create_backend("openai/m", api_base=server.url, tpm=60_000, retry=RetryPolicy(max_retries=0))
        result = asyncio.run(backend.generate([ChatRequest(text="describe", stage="scene", frame_id="f")]))[0]
    assert result.ok and (result.input_tokens, result.output_tokens, result.cost_cents) == (None, None, None)
    assert (
        backend.limiter.tokens.level <= 60_000 - ESTIMATED_TOKENS_PER_CALL + 1000
    )  # refills 1000/s; the call is quick


def test_truncated_texts_are_recorded_asked_again_and_never_passed_on(tmp_path):
    frames = make_frames(tmp_path, 2)
    cut_scene = "CUT-OFF: a two-lane road, a parked van, and the traff"
    cut_answer = GOOD_ACTIONS + " Explanation: the vehicle keeps"  # six valid pairs, then cut off

    def script(req):
        n = sum(1 for r in server.requests if r.stage == req.stage)
        if req.stage == "scene" and n == 1:
            return Reply(cut_scene, finish_reason="length")
        if req.stage == "actions" and n == 1:
            return Reply(cut_answer, finish_reason="length")
        return default_reply(req)

    with FakeOpenAIServer(script) as server:
        result = run(
            "openai/test-model",
            api_base=server.url,
            frames=frames,
            output=tmp_path,
            concurrency=1,
            backoff_base=0.01,
            progress=False,
        )
    assert all(cut_scene not in r.text for r in server.requests if r.stage != "scene")
    first = read_run(result.run_dir).records[frames[0].frame_id]
    attempts = first["attempts"]
    assert [[c["stage"] for c in a["calls"]] for a in attempts] == [
        ["scene"],
        ["scene", "intent", "actions"],
        ["actions"],
    ]
    assert attempts[0]["calls"][0]["text"] == cut_scene and attempts[0]["calls"][0]["finish_reason"] == "length"
    assert (attempts[0]["status"], attempts[0]["failure"], attempts[0]["error"]) == ("failed", "truncated", None)
    assert attempts[0]["reason"].startswith("truncated: the scene text")
    # the cut-off answer holds six valid pairs, and is still not parsed: it is not the whole answer
    assert (attempts[1]["status"], attempts[1]["reason"], attempts[1]["failure"], attempts[1]["answer"]) == (
        "failed",
        "truncated",
        "truncated",
        cut_answer,
    )
    assert attempts[2]["status"] == "ok" and attempts[2]["failure"] == ""
    assert [c["finish_reason"] for a in attempts for c in a["calls"]] == ["length", "stop", "stop", "length", "stop"]
    assert (first["status"], first["first_status"], first["scene_text"]) == ("ok", "failed", SCENE_TEXT)
    assert result.summary["truncated_calls"] == 2 and "2 truncated" in result.report()


def test_frames_cut_off_before_stage_3_are_not_reported_as_api_errors(tmp_path):
    """Every scene text cut off: no stage-3 answer, no API error — the summary says which, as evaluate does."""
    from lightemma.evaluation import evaluate_runs

    frames = make_frames(tmp_path, 3)
    index = FrameIndex(frames)

    def script(req):
        if index(req) == 0 and req.stage == "scene":
            return Reply("a long, long scene descrip", finish_reason="length")
        if index(req) == 1 and req.stage == "intent":
            return Reply.error(500, "unavailable")
        return default_reply(req)

    with FakeOpenAIServer(script) as server:
        result = run(
            "openai/test-model",
            api_base=server.url,
            frames=frames,
            output=tmp_path,
            max_attempts=2,
            max_retries=0,
            backoff_base=0.01,
            progress=False,
        )
    s = result.summary
    assert (s["answered_frames"], s["api_error_frames"], s["cut_off_frames"], s["api_errors"]) == (1, 1, 1, 2)
    assert "(over 1 answered frame(s); API errors only: 1; cut off before stage 3: 1)" in result.report()
    (row,) = evaluate_runs([result.run_dir]).accuracy_rows()
    assert (row["api_errors"], row["failed"]) == (1, 1)


def test_reasoning_models_get_room_for_the_answer_and_their_reasoning_tokens_are_recorded(tmp_path):
    from lightemma.models.catalog import DEFAULT_REASONING_BUDGET

    with FakeOpenAIServer(
        lambda req: Reply(default_reply(req).content, completion_tokens=900, reasoning_tokens=700)
    ) as server:
        result = run(
            "gpt-5",
            api_base=server.url,
            frames=make_frames(tmp_path, 1),
            output=tmp_path,
            backoff_base=0.01,
            progress=False,
        )
    body = server.requests[0].body
    sent = body.get("max_completion_tokens", body.get("max_tokens"))
    assert sent == 512 + DEFAULT_REASONING_BUDGET
    assert result.manifest["params"]["sent"]["max_tokens"] == 512 + DEFAULT_REASONING_BUDGET
    assert result.manifest["backend"]["reasoning"]["budget_tokens"] == DEFAULT_REASONING_BUDGET
    (record,) = read_run(result.run_dir).records.values()
    assert [c["reasoning_tokens"] for c in record["attempts"][0]["calls"]] == [700, 700, 700]
    assert record["reasoning_tokens"] == 2100 and result.summary["mean_reasoning_tokens"] == 2100
    with FakeOpenAIServer() as server:
        plain = run("gpt-4o", api_base=server.url, frames=make_frames(tmp_path, 1), output=tmp_path, progress=False)
    assert plain.manifest["params"]["sent"]["max_tokens"] == 512  # a model that answers directly gets what was asked


def test_a_run_without_one_valid_frame_exits_non_zero(tmp_path, synth_root, capsys):
    def script(req):
        return Reply("I cannot predict the future.") if req.stage == "actions" else default_reply(req)

    with FakeOpenAIServer(script) as server:
        code, out, errors = start(capsys, server, synth_root, tmp_path, "--max-attempts", 2)
    assert code == 1 and len(errors) == 1 and "no valid frame: all 12 frame(s)" in errors[0], errors
    assert "failed 12" in out and read_run(only_run_dir(tmp_path)).complete


def test_images_over_the_providers_limit_are_re_encoded_to_fit_and_the_manifest_says_so(tmp_path):
    frames = make_frames(tmp_path, 3, image_size=(800, 450))
    limit = 24_000
    assert all(os.path.getsize(f.image_path) * 4 / 3 > limit for f in frames)
    with FakeOpenAIServer() as server:
        result = run(
            "openai/test-model",
            api_base=server.url,
            frames=frames,
            output=tmp_path,
            progress=False,
            backend_options={"max_image_bytes": limit},
        )
    for req in server.requests:
        url = next(p["image_url"]["url"] for p in req.body["messages"][-1]["content"] if p["type"] == "image_url")
        assert url.startswith("data:image/jpeg;base64,") and len(url.split(",", 1)[1]) <= limit
    images = result.manifest["sessions"][-1]["images_reencoded"]
    assert images["count"] == 3 and images["limit_base64_chars"] == limit
    example = images["examples"][0]
    assert example["to_bytes"] < example["from_bytes"] and example["original_size"] == [800, 450]
    assert result.manifest["backend"]["image_limit"]["base64_chars"] == limit
    assert result.summary["ok"] == 3


# -- one writer per run directory -----------------------------------------------------------------------------


def test_a_second_writer_is_refused_naming_the_holders_pid(tmp_path, capsys):
    with FakeOpenAIServer() as server:
        result = run(
            "openai/test-model", api_base=server.url, frames=make_frames(tmp_path, 2), output=tmp_path, progress=False
        )
        with RunLock(result.run_dir):
            with pytest.raises(RunStoreError, match=f"another lightemma process \\(PID {os.getpid()}\\)"):
                resume(result.run_dir, api_base=server.url, frames=make_frames(tmp_path, 2), progress=False)
        resume(
            result.run_dir, api_base=server.url, frames=make_frames(tmp_path, 2), progress=False
        )  # released: fine again


@pytest.mark.slow
def test_a_second_process_on_a_run_being_written_is_refused_and_the_first_finishes_alone(tmp_path, synth_root):
    out = tmp_path / "out"
    with FakeOpenAIServer(latency=0.4) as server:
        first = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "lightemma",
                "run",
                "--model",
                "openai/test-model",
                "--api-base",
                server.url,
                "--dataroot",
                str(synth_root),
                "--version",
                "v1.0-mini",
                "--split",
                "all",
                "--concurrency",
                "2",
                "--output",
                str(out),
                "--no-progress",
            ],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        try:
            deadline = time.monotonic() + 60
            while not (out.exists() and store.find_run_dirs(out)) and time.monotonic() < deadline:
                time.sleep(0.05)
            run_dir = only_run_dir(out)
            while not read_run(run_dir).records and time.monotonic() < deadline:
                time.sleep(0.05)  # writing for sure
            calls_before = len(server.requests)
            second = subprocess.run(
                [
                    sys.executable,
                    "-m",
                    "lightemma",
                    "run",
                    "--resume",
                    str(run_dir),
                    "--api-base",
                    server.url,
                    "--no-progress",
                ],
                capture_output=True,
                text=True,
                timeout=120,
            )
            stdout, stderr = first.communicate(timeout=120)
        finally:
            if first.poll() is None:
                first.kill()
    assert second.returncode == 2 and second.stderr.count("\n") == 1, second.stderr
    assert f"another lightemma process (PID {first.pid})" in second.stderr
    assert first.returncode == 0, stderr
    final = read_run(run_dir)
    assert final.complete and len(final.records) == N_FRAMES and final.duplicates == 0
    assert [s["kind"] for s in final.manifest["sessions"]] == ["run"]  # the refused process wrote nothing
    assert len(server.requests) == 3 * N_FRAMES and calls_before <= 3 * N_FRAMES


# -- every exit is one line -----------------------------------------------------------------------------------


def test_a_full_disk_at_the_start_leaves_no_run_directory(tmp_path, synth_root, capsys, monkeypatch):
    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device", str(tmp_path / "x"))

    monkeypatch.setattr(store, "write_json_atomic", full)
    with FakeOpenAIServer() as server:
        code, _, errors = start(capsys, server, synth_root, tmp_path / "out")
        assert not server.requests
    assert code == 2 and len(errors) == 1 and "no space left on the device" in errors[0], errors
    assert store.find_run_dirs(tmp_path / "out") == []
    assert [p.name for p in (tmp_path / "out").rglob("*")] == ["openai--test-model"]  # nothing half-made


def test_a_full_disk_mid_run_stops_with_what_was_written_intact_and_resumable(
    tmp_path, synth_root, capsys, monkeypatch
):
    written = []
    real_append = store.RunWriter.append

    def append(self, record):
        if len(written) >= 3:
            raise OSError(errno.ENOSPC, "No space left on device", str(self.path))
        written.append(record["frame_id"])
        real_append(self, record)

    monkeypatch.setattr(store.RunWriter, "append", append)
    switch = Switch(default_reply)
    with FakeOpenAIServer(switch) as server:
        code, _, errors = start(capsys, server, synth_root, tmp_path)
        assert code == 2 and len(errors) == 1, errors
        assert "no space left on the device" in errors[0] and "lightemma run --resume" in errors[0]
        assert len(server.requests) <= 3 * (3 + 2 * CONCURRENCY)  # three frames, then at most the frames in flight
        run_dir = only_run_dir(tmp_path)
        assert sorted(read_run(run_dir).records) == sorted(written)
        monkeypatch.setattr(store.RunWriter, "append", real_append)  # space freed
        stopped = assert_resumes_to_the_end(capsys, run_dir, switch)
    assert stopped["cause"] == "disk"


def test_an_output_path_that_is_a_file_is_one_line(tmp_path, synth_root, capsys):
    (tmp_path / "runs").write_text("not a directory")
    with FakeOpenAIServer() as server:
        code, _, errors = start(capsys, server, synth_root, tmp_path / "runs")
    assert code == 2 and len(errors) == 1 and "is a file, not a directory" in errors[0] and "--output" in errors[0], (
        errors
    )


def test_a_frame_set_with_no_frames_is_an_error_not_an_empty_run(tmp_path, synth_root, capsys):
    with FakeOpenAIServer() as server:
        code, _, errors = start(capsys, server, synth_root, tmp_path / "out", "--limit", 0)
    assert code == 2 and "--limit must be at least 1" in errors[0]
    # every scene shorter than a window: nothing to run
    short = lightemma.synth.write_dataset(tmp_path / "short", scenes=2, keyframes=10, image_size=(32, 18), sweeps=False)
    with FakeOpenAIServer() as server:
        code, _, errors = run_cli(
            capsys,
            "--model",
            "openai/test-model",
            "--api-base",
            server.url,
            "--dataroot",
            short,
            "--version",
            "v1.0-mini",
            "--split",
            "all",
            "--output",
            tmp_path / "out",
        )
    assert code == 2 and len(errors) == 1 and "no frames to run: every scene was skipped" in errors[0], errors
    assert not (tmp_path / "out").exists()


def test_a_frame_set_whose_images_are_all_missing_says_so(tmp_path, capsys):
    """Not "choose other scenes or --window full": the frames exist, their CAM_FRONT images do not."""
    tables_only = lightemma.synth.write_dataset(tmp_path / "tables", scenes=1, keyframes=15, images=False, sweeps=False)
    code, _, errors = run_cli(
        capsys,
        "--model",
        "baseline:cv",
        "--dataroot",
        tables_only,
        "--version",
        "v1.0-mini",
        "--output",
        tmp_path / "out",
    )
    assert code == 2 and len(errors) == 1, errors
    assert "no frames to run: the CAM_FRONT image of every frame (1) is missing" in errors[0], errors
    assert "--window full" not in errors[0] and "samples/CAM_FRONT" in errors[0], errors
    assert not (tmp_path / "out").exists()


# -- evaluation reads only the run's frame set ------------------------------------------------------------------


def test_evaluate_drops_records_of_frames_outside_the_runs_frame_set(tmp_path, capsys):
    from lightemma.evaluation import evaluate_runs

    with FakeOpenAIServer() as server:
        result = run(
            "openai/test-model", api_base=server.url, frames=make_frames(tmp_path, 4), output=tmp_path, progress=False
        )
    assert (result.run_dir / store.FRAME_IDS_FILE).read_text().splitlines() == [
        f.frame_id for f in make_frames(tmp_path, 4)
    ]
    record = next(iter(read_run(result.run_dir).records.values()))
    with open(result.run_dir / FRAMES_FILE, "a") as fh:
        fh.write(json.dumps({**record, "frame_id": "scene-9999/not-a-frame-of-this-run"}) + "\n")
    evaluation = evaluate_runs([result.run_dir])
    (model,) = evaluation.models
    assert model.frames_in_run == 4
    assert any(
        "dropped 1 record(s) whose frame id is not in the run's frame set" in w and "not-a-frame" in w
        for w in evaluation.warnings
    )
    assert cli_main(["evaluate", str(result.run_dir)]) == 0
    assert "dropped 1 record(s)" in capsys.readouterr().err


def test_evaluate_warns_when_a_finished_run_lost_records(tmp_path, capsys):
    """A finished run whose frames.jsonl lost lines is scored on what is left, and says so (never silently)."""
    from lightemma.evaluation import evaluate_runs

    with FakeOpenAIServer() as server:
        result = run(
            "openai/test-model", api_base=server.url, frames=make_frames(tmp_path, 4), output=tmp_path, progress=False
        )
    assert not any("no record" in w for w in evaluate_runs([result.run_dir]).warnings)
    lines = (result.run_dir / FRAMES_FILE).read_text().splitlines(keepends=True)
    (result.run_dir / FRAMES_FILE).write_text("".join(lines[:3]))
    evaluation = evaluate_runs([result.run_dir])
    assert [
        w
        for w in evaluation.warnings
        if "1 of its 4 frame(s) have no record in frames.jsonl" in w and f"lightemma run --resume {result.run_dir}" in w
    ], evaluation.warnings
    assert cli_main(["evaluate", str(result.run_dir)]) == 0
    assert "1 of its 4 frame(s) have no record" in capsys.readouterr().err


# -- the detectors themselves -----------------------------------------------------------------------------------


def test_the_failure_streak_needs_distinct_frames_and_resets_on_success():
    bad = failure_signature("BadRequestError", "image 1234 too large")
    streak = FailureStreak(cold=3, warm=5)
    assert failure_signature("BadRequestError", "image 99 too large") == bad  # numbers do not make failures different
    assert failure_signature("Timeout", "after 3 s") == failure_signature("Timeout", "after 9 s") == ("Timeout", "")
    for _ in range(10):
        assert streak.observe("scene", "frame-a", bad) is None  # re-asks of one frame count once
    assert streak.observe("scene", "frame-b", bad) is None
    assert streak.observe("scene", "frame-c", bad) == 3  # three frames, nothing ever worked: fatal
    streak = FailureStreak(cold=3, warm=5)
    streak.observe("scene", "frame-a", None)  # something worked: now five frames in a row are needed
    for i in range(4):
        assert streak.observe("scene", f"f{i}", bad) is None
        streak.observe("intent", f"f{i}", None)  # another stage succeeding does not reset the scene stage
    assert streak.observe("scene", "f4", bad) == 5
    streak = FailureStreak(cold=3, warm=5)
    for i in range(50):  # a failure every other frame, successes between: never fatal
        streak.observe("scene", f"f{i}", bad if i % 2 else None)
        assert streak.observe("scene", f"g{i}", None) is None


def test_the_micro_batcher_turns_fatal_only_on_an_identical_exception_in_consecutive_batches_of_distinct_frames():
    def requests(*frames):
        return [ChatRequest(text="t", stage="scene", frame_id=f, params=GenerationParams()) for f in frames]

    calls = []

    def broken(batch):
        calls.append([r.frame_id for r in batch])
        raise AttributeError("no attribute 'image_outputs'")

    async def go(batcher, *batches):
        out = []
        for batch in batches:
            try:
                out.append(await batcher.submit(requests(*batch)))
            except RunFatalError as exc:
                out.append(exc)
        await batcher.aclose()
        return out

    # one frame failing again and again (its own problem): per-frame errors, never fatal
    results = asyncio.run(go(MicroBatcher(broken, batch_size=1, batch_window=0), ["a"], ["a"], ["a"]))
    assert all(isinstance(r, list) and r[0].error == "AttributeError" for r in results)
    # different messages: not the same failure
    counter = iter(range(100))

    def varied(batch):
        raise RuntimeError(f"bad input {next(counter)}")

    results = asyncio.run(go(MicroBatcher(varied, batch_size=1, batch_window=0), ["a"], ["b"], ["c"]))
    assert all(isinstance(r, list) for r in results)
    # the identical exception on two consecutive batches of different frames: fatal, and stays fatal
    results = asyncio.run(
        go(
            MicroBatcher(broken, batch_size=2, batch_window=0, describe_fatal=lambda e: f"cannot: {e}"),
            ["a", "b"],
            ["c", "d"],
            ["e", "f"],
        )
    )
    assert isinstance(results[0], list) and results[0][0].error == "AttributeError"
    assert isinstance(results[1], RunFatalError) and str(results[1]) == "cannot: no attribute 'image_outputs'"
    assert results[2] is results[1] and results[1].cause == "local-model"
    assert calls[-1] == ["c", "d"]  # the third batch never ran


def test_a_stopped_run_raises_run_stopped_from_python_too(tmp_path):
    with FakeOpenAIServer(lambda req: Reply.error(401, "bad key")) as server:
        with pytest.raises(RunStopped) as info:
            run(
                "openai/test-model",
                api_base=server.url,
                frames=make_frames(tmp_path, 6),
                output=tmp_path,
                progress=False,
            )
    assert info.value.cause == "authentication" and info.value.frames_run == 0
    assert read_run(info.value.run_dir).records == {} and np.isscalar(info.value.frames_run)


def test_permission_denied_creating_the_run_directory_is_one_line_and_leaves_nothing(
    tmp_path, synth_root, capsys, monkeypatch
):
    def denied(*args, **kwargs):
        raise PermissionError(errno.EACCES, "Permission denied", str(tmp_path / "out"))

    monkeypatch.setattr(store.tempfile, "mkdtemp", denied)
    with FakeOpenAIServer() as server:
        code, _, errors = start(capsys, server, synth_root, tmp_path / "out")
    assert (
        code == 2
        and len(errors) == 1
        and "cannot create the run directory" in errors[0]
        and "permission denied" in errors[0]
    )
    assert store.find_run_dirs(tmp_path / "out") == []


def test_a_malformed_pose_is_named_in_one_line_or_its_scene_left_out_of_the_run(tmp_path, synth_root, capsys):
    import shutil

    root = tmp_path / "data"
    shutil.copytree(synth_root, root)
    path = root / "v1.0-mini" / "ego_pose.json"
    poses = json.loads(path.read_text())
    frames = lightemma.load_frames(synth_root, "v1.0-mini", split="all")
    first_scene = frames.scenes[0]
    sample = frames[0].sample_token
    (sd,) = [
        s
        for s in json.loads((root / "v1.0-mini" / "sample_data.json").read_text())
        if s["sample_token"] == sample and s["is_key_frame"] and "CAM_FRONT" in s["filename"]
    ]
    (pose,) = [p for p in poses if p["token"] == sd["ego_pose_token"]]
    pose["rotation"] = [0, 0, 0, 0]
    path.write_text(json.dumps(poses))
    with FakeOpenAIServer() as server:
        args = [
            "--model",
            "openai/test-model",
            "--api-base",
            server.url,
            "--dataroot",
            root,
            "--version",
            "v1.0-mini",
            "--split",
            "all",
            "--output",
            tmp_path / "out",
            "--no-progress",
        ]
        code, _, errors = run_cli(capsys, *args, "--on-bad-record", "error")
        assert code == 2 and len(errors) == 1 and not (tmp_path / "out").exists() and not server.requests, errors
        assert (
            f"scene {first_scene}: ego_pose {pose['token']}: field rotation = [0, 0, 0, 0] is not a unit quaternion (norm 0;"
            in errors[0]
        )
        code, _, errors = run_cli(capsys, *args)  # the default: that scene is left out, with a warning
        assert code == 0 and not errors
    contents = read_run(only_run_dir(tmp_path / "out"))
    kept = [f for f in frames.frame_ids if not f.startswith(first_scene + "/")]
    assert sorted(contents.records) == sorted(kept) and len(server.requests) == 3 * len(kept)
    dataset = contents.manifest["dataset"]
    assert dataset["skipped_scenes"] == [first_scene] and pose["token"] in dataset["bad_records"][0]
