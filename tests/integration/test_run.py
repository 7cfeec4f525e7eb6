"""The three-stage chain and the runner, end to end against the loopback server."""

import os

import numpy as np
import pytest

import lightemma
from lightemma.backends.api import FatalBackendError
from lightemma.errors import UserError
from lightemma.pipeline import run
from lightemma.prompts import load_prompt_set
from lightemma.runs.store import FRAMES_FILE, read_run
from tests.support.fake_openai import GOOD_ACTIONS, INTENT_TEXT, SCENE_TEXT, FakeOpenAIServer, Reply, default_reply
from tests.support.memframes import FrameIndex, make_frames

FAST = dict(backoff_base=0.01, backoff_cap=0.05, timeout=5.0, progress=False)
RECORD_FIELDS = {
    "frame_id",
    "scene_name",
    "sample_token",
    "status",
    "first_status",
    "attempts",
    "actions",
    "trajectory",
    "gt_positions",
    "history_actions",
    "seconds",
    "input_tokens",
    "output_tokens",
    "cost_cents",
    "scene_text",
    "intent_text",
    "answer",
    "cached",
}
CORRECTED = "Sure! For the next 6 steps:\nv1 = 5.0, c1 = 0.0\nv2 = 5.0 c2 = 0.0\n5.0 0.0\n5.0 0.0\n5.0 0.0\n5.0 0.0"
GARBAGE = "I cannot predict the future."


@pytest.fixture
def frames(tmp_path):
    return make_frames(tmp_path, 8)


def scripted(frames, per_frame):
    """A server script: ``per_frame(index, stage, nth_call_of_that_stage_for_the_frame)`` -> Reply or None (default)."""
    index = FrameIndex(frames)
    seen = {}

    def script(req):
        i, stage = index(req), req.stage
        n = seen[(i, stage)] = seen.get((i, stage), 0) + 1
        return per_frame(i, stage, n) or default_reply(req)

    return script


def records_of(result, frames=None):
    """The run's records by frame id (file order is completion order), or as a list in ``frames`` order."""
    records = read_run(result.run_dir).records
    return records if frames is None else [records[f.frame_id] for f in frames]


@pytest.mark.parametrize("transport", ["litellm", "direct"])
def test_a_clean_run_records_every_frame_per_spec(tmp_path, frames, transport):
    with FakeOpenAIServer() as server:
        result = run(
            "openai/gpt-4o",
            api_base=server.url,
            frames=frames,
            output=tmp_path / "out",
            concurrency=4,
            transport=transport,
            **FAST,
        )
    records = records_of(result)
    assert sorted(records) == sorted(f.frame_id for f in frames)
    assert server.stages().count("scene") == server.stages().count("intent") == server.stages().count("actions") == 8
    for frame, rec in zip(frames, records_of(result, frames)):
        assert RECORD_FIELDS <= set(rec)
        assert (rec["status"], rec["first_status"], rec["n_attempts"]) == ("ok", "ok", 1)
        assert (rec["scene_text"], rec["intent_text"], rec["answer"]) == (SCENE_TEXT, INTENT_TEXT, GOOD_ACTIONS)
        assert np.allclose(rec["trajectory"], lightemma.integrate(np.array(rec["actions"]), method="euler"))
        assert np.allclose(rec["history_actions"], frame.history_actions) and np.allclose(
            rec["gt_positions"], frame.gt_positions
        )
        assert (rec["input_tokens"], rec["output_tokens"]) == (3000, 150)
        assert rec["cost_cents"] == pytest.approx(3 * (1000 * 2.5e-6 + 50 * 1e-5) * 100)
        assert [c["stage"] for c in rec["attempts"][0]["calls"]] == ["scene", "intent", "actions"]
    manifest = result.manifest
    assert manifest["backend"]["transport"] == transport and manifest["config"]["transport"] == transport
    assert manifest["prompt_set"] == load_prompt_set().describe()
    assert manifest["params"]["sent"] == {"temperature": 0.0, "max_tokens": 512}
    assert manifest["params"]["integrate_method"] == "euler" and manifest["finished_at"]
    assert {"lightemma_version", "git_revision", "started_at", "backend", "dataset"} <= set(manifest)
    summary = result.summary
    assert (summary["frames"], summary["ok"], summary["fe_percent"], summary["fe_corr_percent"]) == (8, 8, 0.0, 0.0)
    assert summary["ade_avg"] == pytest.approx(
        float(
            lightemma.evaluate(
                np.array([r["trajectory"] for r in records.values()]),
                np.array([r["gt_positions"] for r in records.values()]),
            ).ade_avg
        )
    )
    assert "FE" in result.report() and "frames/s" in result.report()


def test_stage_texts_flow_into_the_next_prompts(tmp_path, frames):
    def per_frame(i, stage, n):
        return Reply({"scene": f"SCENE-OF-{i}", "intent": f"INTENT-OF-{i}", "actions": GOOD_ACTIONS}[stage])

    with FakeOpenAIServer(scripted(frames, per_frame)) as server:
        run("openai/test-model", api_base=server.url, frames=frames, output=tmp_path, concurrency=8, **FAST)
    index = FrameIndex(frames)
    for req in server.requests:
        i = index(req)
        assert req.has_image
        if req.stage == "intent":
            assert f"SCENE-OF-{i}" in req.text and "INTENT-OF" not in req.text
            assert f"({5.0 + 0.5 * i}, 0.0)" in req.text  # plain-decimal history
        if req.stage == "actions":
            assert f"SCENE-OF-{i}" in req.text and f"INTENT-OF-{i}" in req.text


def test_malformed_answers_are_reasked_and_counted_as_format_errors(tmp_path, frames):
    def per_frame(i, stage, n):
        if stage != "actions":
            return None
        if i == 0 and n == 1:
            return Reply(GARBAGE)  # FE corr, then fixed by a re-ask
        if i == 1:
            return Reply(CORRECTED)  # FE, corrected by the lenient parser: no re-ask
        if i == 2:
            return Reply(GARBAGE)  # never valid
        return None

    with FakeOpenAIServer(scripted(frames, per_frame)) as server:
        result = run("openai/test-model", api_base=server.url, frames=frames, output=tmp_path, max_attempts=3, **FAST)
    recs = records_of(result, frames)
    assert (recs[0]["first_status"], recs[0]["status"], recs[0]["n_attempts"]) == ("failed", "ok", 2)
    assert [c["stage"] for c in recs[0]["attempts"][1]["calls"]] == ["actions"]  # stage 3 alone re-asked
    assert recs[0]["attempts"][0]["answer"] == GARBAGE and "standalone number" in recs[0]["attempts"][0]["reason"]
    assert (recs[0]["attempts"][0]["failure"], recs[0]["attempts"][1]["failure"], recs[0]["failure"]) == (
        "format",
        "",
        "",
    )
    assert (recs[1]["first_status"], recs[1]["status"], recs[1]["n_attempts"]) == ("corrected", "corrected", 1)
    assert recs[1]["attempts"][0]["reason"]
    assert (recs[2]["status"], recs[2]["n_attempts"], recs[2]["actions"], recs[2]["trajectory"]) == (
        "failed",
        3,
        None,
        None,
    )
    assert recs[2]["input_tokens"] == 5 * 1000  # scene + intent + 3 answers all count
    s = result.summary
    assert (s["ok"], s["corrected"], s["failed"]) == (6, 1, 1)
    assert s["fe_percent"] == pytest.approx(100 * 3 / 8) and s["fe_corr_percent"] == pytest.approx(100 * 2 / 8)
    assert s["ade_frames"] == 7
    assert server.stages().count("scene") == 8  # nothing but stage 3 was re-asked


def test_reask_chain_reruns_all_three_stages(tmp_path, frames):
    def per_frame(i, stage, n):
        return Reply(GARBAGE) if (i == 0 and stage == "actions" and n == 1) else None

    with FakeOpenAIServer(scripted(frames[:1], per_frame)) as server:
        result = run(
            "openai/test-model", api_base=server.url, frames=frames[:1], output=tmp_path, reask="chain", **FAST
        )
    rec = next(iter(records_of(result).values()))
    assert server.stages() == ["scene", "intent", "actions"] * 2
    assert [c["stage"] for c in rec["attempts"][1]["calls"]] == ["scene", "intent", "actions"]
    assert rec["status"] == "ok" and rec["first_status"] == "failed"


def test_api_errors_fail_the_frame_never_the_run_and_never_leak_into_prompts(tmp_path, frames):
    marker = "UPSTREAM-EXPLODED"

    def per_frame(i, stage, n):
        if i == 3 and stage == "intent":
            return Reply.error(500, marker)  # intent never succeeds
        if i == 4 and stage == "scene" and n <= 3:
            return Reply.error(503, marker)  # first attempt's scene fails after retries, then works
        return None

    with FakeOpenAIServer(scripted(frames, per_frame)) as server:
        result = run(
            "openai/test-model",
            api_base=server.url,
            frames=frames,
            output=tmp_path,
            max_retries=2,
            max_attempts=2,
            **FAST,
        )
    recs = records_of(result)
    bad, flaky = recs[frames[3].frame_id], recs[frames[4].frame_id]
    # no answer was ever received: not a format error, counted apart
    assert (bad["status"], bad["first_status"], bad["error"], bad["n_attempts"]) == (
        "failed",
        None,
        "InternalServerError",
        2,
    )
    assert bad["failure"] == "api_error" and [a["failure"] for a in bad["attempts"]] == ["api_error", "api_error"]
    assert bad["attempts"][0]["calls"][-1]["text"] is None and bad["attempts"][0]["answer"] is None
    assert bad["attempts"][0]["calls"][-1]["retries"] == 2
    assert [c["stage"] for c in bad["attempts"][1]["calls"]] == ["intent"]  # the failed stage is redone, not stage 1
    # the first answer received is attempt 2's, which is ok
    assert (flaky["status"], flaky["first_status"], flaky["n_attempts"], flaky["failure"]) == ("ok", "ok", 2, "")
    assert flaky["attempts"][0]["error"] == "ServiceUnavailableError"
    assert all(marker not in req.text and "Error" not in req.text for req in server.requests)
    assert result.summary["failed"] == 1 and result.summary["api_errors"] == 3
    s = result.summary
    assert (s["api_error_frames"], s["answered_frames"], s["fe_percent"], s["fe_corr_percent"]) == (
        1,
        len(frames) - 1,
        0.0,
        0.0,
    )
    assert "API errors only: 1" in result.report()


def test_unknown_price_gives_null_cost(tmp_path, frames):
    with FakeOpenAIServer() as server:
        result = run("openai/no-such-model-xyz", api_base=server.url, frames=frames[:2], output=tmp_path, **FAST)
    assert all(r["cost_cents"] is None for r in records_of(result).values())
    assert result.summary["total_cost_cents"] is None and result.summary["frames_cost_unknown"] == 2


def test_api_keys_never_appear_in_any_file_the_run_writes(tmp_path, frames, monkeypatch):
    secret = "sk-proj-NEVERWRITE-abcdef0123456789"
    monkeypatch.setenv("OPENAI_API_KEY", secret)

    def per_frame(i, stage, n):
        return Reply.error(400, f"invalid request for key {secret}") if i == 0 else None

    with FakeOpenAIServer(scripted(frames, per_frame)) as server:
        result = run(
            "openai/gpt-4o",
            api_base=server.url,
            frames=frames,
            output=tmp_path / "out",
            cache=True,
            api_key_env="OPENAI_API_KEY",
            **FAST,
        )
    assert server.requests[0].headers["authorization"] == f"Bearer {secret}"
    assert records_of(result)[frames[0].frame_id]["status"] == "failed"
    written = [p for p in (tmp_path / "out").rglob("*") if p.is_file()]
    assert any(p.name == FRAMES_FILE for p in written) and any(p.suffix == ".sqlite" for p in written)
    for path in written:
        assert secret.encode() not in path.read_bytes(), path
        assert b"NEVERWRITE" not in path.read_bytes(), path


def test_a_key_in_backend_options_is_refused_since_the_manifest_records_them(tmp_path, frames):
    secret = "sk-proj-NEVERWRITE-abcdef0123456789"
    with FakeOpenAIServer() as server:
        with pytest.raises(UserError, match="api_key"):
            run(
                "openai/gpt-4o",
                api_base=server.url,
                frames=frames[:1],
                output=tmp_path / "out",
                backend_options={"api_key": secret},
                **FAST,
            )
    assert not (tmp_path / "out").exists() and not server.requests


def test_a_missing_api_key_fails_before_any_work(tmp_path, frames, monkeypatch):
    monkeypatch.delenv("OPENAI_API_KEY", raising=False)
    with pytest.raises(UserError, match="OPENAI_API_KEY"):
        run("gpt-4o", frames=frames, output=tmp_path / "out", **FAST)
    assert not (tmp_path / "out").exists()


def test_a_rejected_key_stops_the_run_which_stays_resumable(tmp_path, frames):
    with FakeOpenAIServer(lambda req: Reply.error(401, "bad key")) as server:
        with pytest.raises(FatalBackendError, match="AuthenticationError"):
            run("openai/test-model", api_base=server.url, frames=frames, output=tmp_path, **FAST)
    (run_dir,) = [p.parent for p in tmp_path.rglob("manifest.json")]
    contents = read_run(run_dir)
    assert contents.records == {} and not contents.complete


def test_the_response_cache_is_recorded_per_call(tmp_path, frames):
    with FakeOpenAIServer() as server:
        first = run("openai/gpt-4o", api_base=server.url, frames=frames[:2], output=tmp_path, cache=True, **FAST)
        second = run("openai/gpt-4o", api_base=server.url, frames=frames[:2], output=tmp_path, cache=True, **FAST)
    assert len(server.requests) == 6  # the second run was served from the cache
    recs = list(records_of(second).values())
    assert all(r["cached"] and r["cached_calls"] == 3 and r["cost_cents"] == 0.0 for r in recs)
    assert not any(r["cached"] for r in records_of(first).values())
    assert second.summary["cached_calls"] == 6
    assert first.manifest["backend"]["cache"] == second.manifest["backend"]["cache"] == str(tmp_path / "cache.sqlite")


def test_many_frames_are_in_flight_at_once(tmp_path):
    frames = make_frames(tmp_path, 16)
    with FakeOpenAIServer(latency=1.0) as server:
        result = run("openai/test-model", api_base=server.url, frames=frames, output=tmp_path, concurrency=16, **FAST)
    # each call waits 1 s at the server: frames run one at a time would never overlap there
    assert server.max_in_flight >= 8, server.max_in_flight
    assert len(records_of(result)) == 16


def test_invalid_settings_are_refused_before_any_work(tmp_path, frames):
    for bad in (dict(reask="sometimes"), dict(max_attempts=0), dict(integrate_method="rk4"), dict(concurrency=0)):
        with pytest.raises((UserError, ValueError)):
            run(
                "openai/test-model",
                api_base="http://127.0.0.1:9/v1",
                frames=frames,
                output=tmp_path / "x",
                **{**FAST, **bad},
            )
    assert not (tmp_path / "x").exists()


def cli(*args, env=None):
    """Run ``python -m lightemma`` in a subprocess; returns the CompletedProcess."""
    import subprocess
    import sys

    merged = {**os.environ, **(env or {})}
    return subprocess.run(
        [sys.executable, "-m", "lightemma", *map(str, args)],
        capture_output=True,
        text=True,
        timeout=120,
        env={k: v for k, v in merged.items() if v is not None},
    )


@pytest.mark.slow
def test_cli_run_over_a_synthetic_dataset(tmp_path, synth_root):
    with FakeOpenAIServer() as server:
        done = cli(
            "run",
            "--model",
            "openai/gpt-4o",
            "--api-base",
            server.url,
            "--dataroot",
            synth_root,
            "--version",
            "v1.0-mini",
            "--split",
            "all",
            "--limit",
            10,
            "--concurrency",
            4,
            "--output",
            tmp_path,
            "--no-progress",
        )
    assert done.returncode == 0, done.stderr
    assert "FE" in done.stdout and "ADE avg" in done.stdout and "run directory:" in done.stderr
    (run_dir,) = [p.parent for p in tmp_path.rglob("manifest.json")]
    assert run_dir.parent.name == "openai--gpt-4o"
    contents = read_run(run_dir)
    assert len(contents.records) == 10 and contents.complete
    frames = lightemma.load_frames(synth_root, "v1.0-mini", split="all").head(10)
    assert set(contents.records) == set(frames.frame_ids)
    manifest = contents.manifest
    assert manifest["dataset"]["version"] == "v1.0-mini" and manifest["dataset"]["n_frames"] == 10
    assert manifest["config"]["dataset"]["limit"] == 10
    rec = contents.records[frames.frame_ids[0]]
    assert np.allclose(rec["gt_positions"], frames[0].gt_positions)
    assert lightemma.frames.format_history(frames[0].history_actions) in server.requests[1].text or any(
        lightemma.frames.format_history(frames[0].history_actions) in r.text for r in server.requests
    )


@pytest.mark.slow
def test_cli_reports_a_missing_key_and_bad_usage_in_one_line(tmp_path, synth_root, capsys, monkeypatch):
    done = cli(
        "run",
        "--model",
        "gpt-4o",
        "--dataroot",
        synth_root,
        "--version",
        "v1.0-mini",
        "--split",
        "all",
        "--output",
        tmp_path,
        env={"OPENAI_API_KEY": None},
    )
    assert done.returncode == 2 and "OPENAI_API_KEY" in done.stderr and "Traceback" not in done.stderr
    assert not list(tmp_path.iterdir())
    from lightemma.cli import main

    monkeypatch.delenv("LIGHTEMMA_DEBUG", raising=False)
    assert main(["run", "--retry-failed", "--model", "gpt-4o", "--dataroot", str(synth_root)]) == 2
    assert "--retry-failed needs --resume" in capsys.readouterr().err
    assert main(["run", "--resume", str(tmp_path), "--model", "gpt-4o"]) == 2
    assert "drop --model" in capsys.readouterr().err
    assert main(["run", "--resume", str(tmp_path)]) == 2
    assert "not a lightemma run directory" in capsys.readouterr().err


def test_cli_resume_refuses_what_it_would_ignore_and_takes_how_long_and_how_fast(tmp_path, capsys, monkeypatch):
    from lightemma.cli import main

    monkeypatch.delenv("LIGHTEMMA_DEBUG", raising=False)
    for flags in (["--backend", "api"], ["--max-tokens", "64"]):  # --cache, --api-base: checked against the run
        assert main(["run", "--resume", str(tmp_path), *flags]) == 2
        assert f"drop {flags[0]}" in capsys.readouterr().err
    for flags in (["--rpm", "10"], ["--tpm", "1000"], ["--timeout", "30"]):  # taken: the run directory is checked next
        assert main(["run", "--resume", str(tmp_path), *flags]) == 2
        assert "not a lightemma run directory" in capsys.readouterr().err


def test_cli_resume_refuses_every_run_setting_even_one_given_at_its_default(tmp_path, capsys, monkeypatch):
    from lightemma.cli import main
    from lightemma.cli.run import RESUME_OPTIONS, RUN_DEFAULTS

    monkeypatch.delenv("LIGHTEMMA_DEBUG", raising=False)
    for name, default in RUN_DEFAULTS.items():
        if name in RESUME_OPTIONS:  # how long to wait for a call (--timeout): a resume takes it
            continue
        flag = "--" + name.replace("_", "-")
        values = [str(v) for v in default] if isinstance(default, tuple) else [str(default)]
        assert main(["run", "--resume", str(tmp_path), flag, *values]) == 2
        assert f"drop {flag}" in capsys.readouterr().err, flag
    # what resume does take is not refused: the run directory itself is then checked
    assert main(["run", "--resume", str(tmp_path), "--concurrency", "4", "--no-progress"]) == 2
    assert "not a lightemma run directory" in capsys.readouterr().err


def test_an_empty_answer_fails_the_attempt_and_is_reasked(tmp_path, frames):
    def per_frame(i, stage, n):
        return Reply("") if (i == 0 and stage == "actions" and n == 1) else None

    with FakeOpenAIServer(scripted(frames[:1], per_frame)) as server:
        result = run("openai/test-model", api_base=server.url, frames=frames[:1], output=tmp_path, **FAST)
    rec = records_of(result, frames[:1])[0]
    assert (rec["first_status"], rec["status"], rec["n_attempts"]) == ("failed", "ok", 2)
    assert rec["attempts"][0]["error"] == "EmptyResponse" and rec["attempts"][0]["answer"] is None
    assert rec["attempts"][0]["failure"] == "format"  # an empty answer was received: a format error, not an API error
    assert rec["input_tokens"] == 4000  # the empty answer's usage counts
    assert server.stages() == ["scene", "intent", "actions", "actions"]


def test_baselines_run_through_the_same_chain_without_any_key(tmp_path, synth_root, monkeypatch):
    for name in ("OPENAI_API_KEY", "ANTHROPIC_API_KEY", "GEMINI_API_KEY", "GOOGLE_API_KEY"):
        monkeypatch.delenv(name, raising=False)
    result = run(
        "baseline:oracle", dataroot=synth_root, version="v1.0-mini", split="all", output=tmp_path, progress=False
    )
    records = records_of(result)
    assert len(records) == result.manifest["dataset"]["n_frames"] == 12
    assert all(
        r["status"] == "ok" and [c["stage"] for c in r["attempts"][0]["calls"]] == ["scene", "intent", "actions"]
        for r in records.values()
    )
    assert result.manifest["backend"]["kind"] == "oracle" and result.manifest["model_info"]["family"] == "baseline"
    assert result.summary["ade_avg"] < 0.5  # the oracle's own future actions, integrated


IMPLAUSIBLE = "[(5254, 0.001), (5559, 0.001), (5864, 0.001), (6170, 0.001), (6475, 0.001), (6780, 0.001)]"
FAST_45 = "[(45.0, 0.0), (45.0, 0.0), (45.0, 0.0), (45.0, 0.0), (45.0, 0.0), (45.0, 0.0)]"


def test_plausibility_limits_are_run_settings_recorded_and_kept_by_resume(tmp_path, frames):
    from lightemma.pipeline import resume
    from lightemma.runs.store import read_manifest

    def per_frame(i, stage, n):
        if stage == "actions" and i == 0 and n == 1:
            return Reply(IMPLAUSIBLE)  # lost decimal points: implausible, re-asked
        if stage == "actions" and i == 1:
            return Reply(FAST_45)  # plausible by default, not under --speed-range 0 40
        return None

    with FakeOpenAIServer(scripted(frames[:2], per_frame)) as server:
        result = run(
            "openai/test-model",
            api_base=server.url,
            frames=frames[:2],
            output=tmp_path,
            max_attempts=2,
            speed_range=(0, 40),
            max_abs_curvature=0.5,
            **FAST,
        )
        first, fast = records_of(result, frames[:2])
        assert (first["first_status"], first["status"]) == ("failed", "ok")
        assert first["attempts"][0]["failure"] == "implausible"
        assert first["attempts"][0]["reason"] == "speed 5254 at step 1 outside [0, 40] m/s"
        assert (fast["status"], fast["failure"], fast["n_attempts"]) == ("failed", "implausible", 2)
        manifest = read_manifest(result.run_dir)
        assert manifest["params"]["parse"] == {"mode": "lenient", "speed_range": [0.0, 40.0], "max_abs_curvature": 0.5}
        assert result.summary["fe_corr_percent"] == 100.0
        # a resume parses with the run's own limits: the 45 m/s answers still fail
        again = resume(result.run_dir, api_base=server.url, retry_failed=True, frames=frames[:2], progress=False)
        assert records_of(again, frames[:2])[1]["failure"] == "implausible"
    with FakeOpenAIServer(scripted(frames[:2], per_frame)) as server:
        plain = run("openai/test-model", api_base=server.url, frames=frames[1:2], output=tmp_path / "default", **FAST)
        assert records_of(plain, frames[1:2])[0]["status"] == "ok"  # 45 m/s is within the default [-10, 50]
        assert read_manifest(plain.run_dir)["params"]["parse"]["speed_range"] == [-10.0, 50.0]


def test_runs_recorded_before_the_limits_resume_without_them():
    from lightemma.pipeline.config import RunConfig
    from lightemma.pipeline.runner import _policy

    # a manifest's config written before the limits existed: without speed_range and max_abs_curvature
    config = {
        k: v
        for k, v in RunConfig.of("baseline:cv").to_manifest().items()
        if k not in ("speed_range", "max_abs_curvature")
    }
    policy = _policy(RunConfig.from_manifest(config))
    assert (policy.speed_range, policy.max_abs_curvature) == (None, None)
    assert policy.parse_record() == {"mode": "lenient", "speed_range": None, "max_abs_curvature": None}
    limited = RunConfig.from_manifest({**config, "speed_range": [0, 30], "max_abs_curvature": 0.2})
    assert _policy(limited).speed_range == (0, 30)


def test_cli_plausibility_flags(tmp_path, synth_root, capsys, monkeypatch):
    from lightemma.cli import main
    from lightemma.runs.store import find_run_dirs, read_manifest

    monkeypatch.delenv("LIGHTEMMA_DEBUG", raising=False)
    base = [
        "run",
        "--model",
        "baseline:oracle",
        "--dataroot",
        str(synth_root),
        "--version",
        "v1.0-mini",
        "--split",
        "all",
        "--limit",
        "2",
        "--no-progress",
        "--output",
        str(tmp_path),
    ]
    assert main([*base, "--speed-range", "50", "-10"]) == 2
    assert (
        "lightemma run: error: --speed-range LO HI needs two finite numbers with LO < HI, got 50 -10"
        in capsys.readouterr().err
    )
    assert main([*base, "--max-curvature", "0"]) == 2
    assert "--max-curvature must be a finite number > 0" in capsys.readouterr().err
    assert main([*base, "--speed-range", "-5", "30", "--max-curvature", "0.25"]) == 0
    (run_dir,) = find_run_dirs(tmp_path)
    assert read_manifest(run_dir)["params"]["parse"] == {
        "mode": "lenient",
        "speed_range": [-5.0, 30.0],
        "max_abs_curvature": 0.25,
    }
    assert main(["run", "--resume", str(run_dir), "--max-curvature", "0.3"]) == 2
    assert "drop --max-curvature" in capsys.readouterr().err
