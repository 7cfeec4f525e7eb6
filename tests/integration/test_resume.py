"""Crash safety and resume: SIGKILL mid-run, truncated tails, --retry-failed, prompt-hash guard."""

import json
import signal
import subprocess
import sys
import time
from collections import Counter

import pytest

from lightemma.errors import UserError
from lightemma.pipeline import resume, run
from lightemma.runs.store import FRAMES_FILE, read_manifest, read_run, update_manifest
from tests.support.fake_openai import FakeOpenAIServer, Reply, default_reply
from tests.support.memframes import FrameIndex, make_frames

FAST = dict(backoff_base=0.01, backoff_cap=0.05, progress=False)


def lines_of(run_dir):
    """Every line of frames.jsonl parsed (fails on a corrupt line)."""
    return [json.loads(line) for line in (run_dir / FRAMES_FILE).read_text().splitlines()]


def visible(paths, root):
    """``paths`` outside hidden directories (a run directory is written in a hidden one, then renamed into place)."""
    return [p for p in paths if not any(part.startswith(".") for part in p.relative_to(root).parts)]


def wait_for_lines(path, n, timeout=30.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if path.exists() and path.read_bytes().count(b"\n") >= n:
            return
        time.sleep(0.02)
    raise AssertionError(f"{path} never reached {n} lines")


@pytest.mark.slow
def test_sigkill_mid_run_then_resume_records_every_frame_exactly_once(tmp_path, synth_root):
    """`lightemma run` killed with SIGKILL after a few frames; `--resume RUN_DIR` alone finishes it."""
    import lightemma

    frame_ids = lightemma.load_frames(synth_root, "v1.0-mini", split="all").frame_ids
    n = len(frame_ids)
    out = tmp_path / "out"
    with FakeOpenAIServer(latency=0.05) as server:
        command = [
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
        ]
        proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        try:
            deadline = time.monotonic() + 60
            while not visible(out.rglob(FRAMES_FILE), out) and time.monotonic() < deadline:
                time.sleep(0.02)
            (frames_file,) = visible(out.rglob(FRAMES_FILE), out)
            wait_for_lines(frames_file, 3)
            proc.send_signal(signal.SIGKILL)
            proc.wait(timeout=10)
        finally:
            if proc.poll() is None:
                proc.kill()
        run_dir = frames_file.parent
        killed = read_run(run_dir)
        assert proc.returncode == -signal.SIGKILL
        assert not killed.complete and 3 <= len(killed.records) < n, proc.stderr.read().decode()[-2000:]
        # a crash in the middle of a write leaves a fragment: simulate one on top of the kill
        with open(frames_file, "ab") as fh:
            fh.write(b'{"frame_id": "synth-0000-cruise/tok')
        assert read_run(run_dir).truncated_tail
        before = len(server.requests)
        resumed = subprocess.run(
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
        assert resumed.returncode == 0, resumed.stderr
    assert f"{len(killed.records)} frame(s) recorded, {n - len(killed.records)} to run" in resumed.stderr
    assert len(server.requests) - before == 3 * (n - len(killed.records))
    counts = Counter(rec["frame_id"] for rec in lines_of(run_dir))
    assert counts == Counter(frame_ids)  # every frame exactly once, no corrupt line
    final = read_run(run_dir)
    assert final.complete and not final.truncated_tail and not final.corrupt_lines and final.duplicates == 0
    assert [s["kind"] for s in read_manifest(run_dir)["sessions"]] == ["run", "resume"]
    assert final.manifest["summary"]["frames"] == n and final.manifest["summary"]["ok"] == n


def test_resume_after_a_truncated_file_redoes_only_missing_frames(tmp_path):
    frames = make_frames(tmp_path, 6)
    with FakeOpenAIServer() as server:
        first = run("openai/test-model", api_base=server.url, frames=frames, output=tmp_path, **FAST)
        path = first.run_dir / FRAMES_FILE
        lines = path.read_bytes().splitlines(keepends=True)
        path.write_bytes(b"".join(lines[:4]) + lines[4][: len(lines[4]) // 2])  # lost frames 5, 6 (one half-written)
        kept = {json.loads(line)["frame_id"] for line in lines[:4]}
        before = len(server.requests)
        result = resume(first.run_dir, api_base=server.url, frames=frames, progress=False)
    assert result.frames_run == 2 and len(server.requests) - before == 6
    assert Counter(r["frame_id"] for r in lines_of(first.run_dir)) == Counter(f.frame_id for f in frames)
    assert kept <= set(read_run(first.run_dir).records)


def test_resume_of_a_finished_run_does_nothing(tmp_path):
    frames = make_frames(tmp_path, 3)
    with FakeOpenAIServer() as server:
        first = run("openai/test-model", api_base=server.url, frames=frames, output=tmp_path, **FAST)
        before = len(server.requests)
        again = resume(first.run_dir, api_base=server.url, frames=frames, progress=False)
    assert again.frames_run == 0 and len(server.requests) == before and again.summary["frames"] == 3


def test_retry_failed_reruns_only_failed_frames_and_the_last_record_wins(tmp_path):
    frames = make_frames(tmp_path, 6)
    index = FrameIndex(frames)
    broken = {1, 4}
    fixed = {"now": False}

    def script(req):
        if req.stage == "actions" and index(req) in broken and not fixed["now"]:
            return Reply("no idea")
        return default_reply(req)

    with FakeOpenAIServer(script) as server:
        first = run("openai/test-model", api_base=server.url, frames=frames, output=tmp_path, max_attempts=2, **FAST)
        assert first.summary["failed"] == 2
        fixed["now"] = True
        before = len(server.requests)
        plain = resume(first.run_dir, api_base=server.url, frames=frames, progress=False)
        assert plain.frames_run == 0 and len(server.requests) == before  # failed frames are finished frames
        again = resume(first.run_dir, api_base=server.url, retry_failed=True, frames=frames, progress=False)
    assert again.frames_run == 2 and len(server.requests) - before == 2 * 3
    contents = read_run(first.run_dir)
    assert contents.duplicates == 2 and all(r["status"] == "ok" for r in contents.records.values())
    assert again.summary["failed"] == 0 and again.summary["ok"] == 6
    # the retried frames keep their earlier attempts: FE still counts the first answer ever received ("no idea"),
    # and the frame's calls, tokens and time include what the failed attempts spent
    earlier = [r for r in read_jsonl_lines(first.run_dir) if r["status"] == "failed"]
    for old in earlier:
        new = contents.records[old["frame_id"]]
        assert (new["first_status"], new["n_attempts"]) == ("failed", 3)
        assert [a["attempt"] for a in new["attempts"]] == [1, 2, 3]
        assert [a["status"] for a in new["attempts"]] == ["failed", "failed", "ok"] and new["attempts"][:2] == old[
            "attempts"
        ]
        assert new["input_tokens"] > old["input_tokens"] and new["seconds"] >= old["seconds"]
    assert again.summary["fe_corr_percent"] == pytest.approx(100 * 2 / 6)


def test_with_the_response_cache_a_reask_and_a_retry_reach_the_provider_not_the_cached_failure(tmp_path):
    """A re-ask (attempt 2) and a --retry-failed pass (attempts 3, 4) are new questions: the cache never replays the
    failed answer they are asked again for. A second identical run still replays every attempt from the cache."""
    frames = make_frames(tmp_path, 1)
    fixed = {"now": False}

    def script(req):
        if req.stage == "actions" and not fixed["now"]:
            return Reply("no idea")
        return default_reply(req)

    with FakeOpenAIServer(script) as server:
        first = run(
            "openai/test-model",
            api_base=server.url,
            frames=frames,
            output=tmp_path / "a",
            max_attempts=2,
            cache=True,
            **FAST,
        )
        asked = [r.stage for r in server.requests]
        assert asked == ["scene", "intent", "actions", "actions"], asked  # the re-ask went to the server
        assert first.summary["failed"] == 1 and first.summary["cached_calls"] == 0
        fixed["now"] = True
        again = resume(first.run_dir, api_base=server.url, cache=True, retry_failed=True, frames=frames, progress=False)
        assert [r.stage for r in server.requests[len(asked) :]] == ["scene", "intent", "actions"]
        sent = len(server.requests)
        # the same run again, sharing the cache: both attempts are replayed, nothing is sent
        replay = run(
            "openai/test-model",
            api_base=server.url,
            frames=frames,
            output=tmp_path / "a",
            max_attempts=2,
            cache=tmp_path / "a" / "cache.sqlite",
            **FAST,
        )
        assert len(server.requests) == sent and replay.summary["failed"] == 1 and replay.summary["cached_calls"] == 4
    (record,) = read_run(first.run_dir).records.values()
    assert record["status"] == "ok" and [a["attempt"] for a in record["attempts"]] == [1, 2, 3]
    assert [c["cached"] for a in record["attempts"] for c in a["calls"]] == [False] * 7
    assert again.summary["ok"] == 1


def test_resume_refuses_a_changed_prompt_set(tmp_path):
    frames = make_frames(tmp_path, 2)
    with FakeOpenAIServer() as server:
        first = run("openai/test-model", api_base=server.url, frames=frames, output=tmp_path, **FAST)
    update_manifest(first.run_dir, prompt_set={"name": "lightemma-v1", "hash": "sha256:0000"})
    with pytest.raises(UserError, match="prompt set 'lightemma-v1' has changed"):
        resume(first.run_dir, api_base=server.url, frames=frames, progress=False)


def test_resume_of_a_run_with_a_prompt_set_file(tmp_path, monkeypatch):
    from lightemma.prompts import load_prompt_set

    shipped = load_prompt_set()
    data = {"name": "my-prompts", "description": "", "stages": dict(shipped.stages)}
    (tmp_path / "mine.json").write_text(json.dumps(data), encoding="utf-8")
    frames = make_frames(tmp_path, 3)
    monkeypatch.chdir(tmp_path)
    with FakeOpenAIServer() as server:
        first = run(
            "openai/test-model", api_base=server.url, frames=frames, output=tmp_path, prompt_set="mine.json", **FAST
        )
        path = first.run_dir / FRAMES_FILE
        path.write_bytes(b"".join(path.read_bytes().splitlines(keepends=True)[:2]))  # lost the last frame
        monkeypatch.chdir(first.run_dir)  # resumed from elsewhere: the file is found all the same
        result = resume(first.run_dir, api_base=server.url, frames=frames, progress=False)
    assert result.frames_run == 1 and result.summary["frames"] == 3
    assert result.manifest["prompt_set"]["name"] == "my-prompts"


def test_resume_of_in_memory_frames_needs_them_and_a_foreign_dir_is_refused(tmp_path):
    frames = make_frames(tmp_path, 2)
    with FakeOpenAIServer() as server:
        first = run("openai/test-model", api_base=server.url, frames=frames, output=tmp_path, **FAST)
    with pytest.raises(UserError, match="frames passed in memory"):
        resume(first.run_dir, api_base=server.url, progress=False)
    with pytest.raises(UserError, match="not a lightemma run directory"):
        resume(tmp_path, progress=False)


def test_ctrl_c_records_the_sessions_wall_time_so_the_resumed_run_has_one(tmp_path, monkeypatch):
    """Ctrl-C saves the interrupted session's wall time: evaluate sums the sessions instead of showing '-'."""
    import asyncio

    from lightemma.evaluation import evaluate_runs
    from lightemma.pipeline import runner

    frames = make_frames(tmp_path, 3)

    async def interrupted(*args, **kwargs):
        await asyncio.sleep(0.2)
        raise KeyboardInterrupt

    with FakeOpenAIServer() as server:
        with monkeypatch.context() as patch:
            patch.setattr(runner, "_execute", interrupted)
            with pytest.raises(KeyboardInterrupt):
                run("openai/test-model", api_base=server.url, frames=frames, output=tmp_path, **FAST)
        (run_dir,) = [p.parent for p in tmp_path.rglob("manifest.json")]
        first = read_manifest(run_dir)["sessions"][0]
        assert first["interrupted"] is True and first["wall_seconds"] >= 0.2
        assert read_manifest(run_dir).get("finished_at") is None
        resume(run_dir, api_base=server.url, frames=frames, progress=False)
    sessions = read_manifest(run_dir)["sessions"]
    row = evaluate_runs([run_dir]).efficiency_rows()[0]
    assert row["run_wall_seconds"] == pytest.approx(sessions[0]["wall_seconds"] + sessions[1]["wall_seconds"])
    assert row["frames_per_second"] == pytest.approx(3 / row["run_wall_seconds"])


def read_jsonl_lines(run_dir):
    """Every record line of a run, in the order written (duplicates included)."""
    import json

    return [json.loads(line) for line in (run_dir / "frames.jsonl").read_text().splitlines() if line.strip()]
