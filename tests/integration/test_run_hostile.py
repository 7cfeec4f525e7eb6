"""Runs that no provider, file or signal can hang, crash or turn against the user (issue 25, and 22.5).

Every test drives the real code against loopback servers (tests/support/fake_openai.py), crafted run
directories or a subprocess it signals; none reaches the network.
"""

from __future__ import annotations

import asyncio
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from lightemma.pipeline import run
from lightemma.prompts import load_prompt_set
from lightemma.runs.store import read_run
from tests.support.fake_openai import INTENT_TEXT, FakeOpenAIServer, Reply, default_reply
from tests.support.memframes import make_frames

FAST = dict(backoff_base=0.01, backoff_cap=0.05, timeout=10.0, progress=False)
ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture
def frames(tmp_path):
    return make_frames(tmp_path, 3)


def env(**extra: str) -> dict[str, str]:
    """The environment of a lightemma subprocess: this checkout's code, no network for HF or litellm."""
    out = {k: v for k, v in os.environ.items() if not k.endswith("_API_KEY")}
    out.update(
        PYTHONPATH=str(ROOT / "python") + os.pathsep + str(ROOT),
        HF_HUB_OFFLINE="1",
        LITELLM_LOCAL_MODEL_COST_MAP="True",
        PYTHONUNBUFFERED="1",
        **extra,
    )
    return out


# -- 25.14: a model's text is data, never a template --------------------------------------------------


def test_placeholders_in_a_models_answer_are_not_expanded_in_the_next_prompt():
    ps = load_prompt_set()
    scene = "a sign reads {intent} and {history} and {speeds}"
    intent = ps.render("intent", scene=scene, history="HIST", speeds="S", curvatures="C")
    assert scene in intent and "HIST" in intent  # the template's own {history} is filled, the scene's is not
    actions = ps.render(
        "actions", scene=scene, intent="go {scene} {curvatures}", history="HIST", speeds="S", curvatures="C"
    )
    assert scene in actions and "go {scene} {curvatures}" in actions


def test_a_chain_passes_a_scene_text_holding_placeholders_on_verbatim(tmp_path, frames):
    scene = "Road ahead; a billboard says {intent} {history} {scene}."

    def script(req):
        return Reply(scene) if req.stage == "scene" else default_reply(req)

    with FakeOpenAIServer(script) as server:
        result = run("openai/test-model", frames=frames[:1], api_base=server.url, output=tmp_path / "out", **FAST)
    by_stage = {r.stage: r.text for r in server.requests}
    assert scene in by_stage["intent"] and scene in by_stage["actions"]
    assert INTENT_TEXT in by_stage["actions"] and by_stage["actions"].count(INTENT_TEXT) == 1
    assert read_run(result.run_dir).records[frames[0].frame_id]["status"] == "ok"


# -- 25.1: a provider's Retry-After never freezes a run ------------------------------------------------


@pytest.mark.parametrize("after", ["3600", "inf", "Wed, 21 Oct 2099 07:28:00 GMT"])
@pytest.mark.parametrize("transport", ["litellm", "direct"])
def test_a_retry_after_beyond_the_maximum_wait_stops_the_run_at_once_resumable(tmp_path, frames, after, transport):
    from lightemma.errors import RunStopped

    replies = [
        Reply(
            status=429,
            headers={"Retry-After": after},
            body={"error": {"message": "quota", "type": "rate_limit_exceeded"}},
        )
    ]
    with FakeOpenAIServer(replies) as server:
        start = time.monotonic()
        with pytest.raises(RunStopped) as info:
            run(
                "openai/test-model",
                frames=frames,
                api_base=server.url,
                output=tmp_path / "out",
                concurrency=1,
                transport=transport,
                **FAST,
            )
        elapsed = time.monotonic() - start
    assert elapsed < 15, elapsed  # not an hour, not forever
    assert info.value.cause == "quota-exhausted" and "Retry-After" in str(info.value) and "--resume" in str(info.value)
    assert len(server.requests) == 1  # nothing else is sent into a quota the provider says is gone


def test_a_short_retry_after_is_waited_and_no_pause_exceeds_the_cap():
    from lightemma.backends.ratelimit import MAX_PAUSE, RateLimiter
    from lightemma.backends.retry import RetryPolicy, _parse_retry_after

    limiter = RateLimiter()
    limiter.pause(float("inf"))
    assert limiter._paused_until - time.monotonic() <= MAX_PAUSE
    assert RetryPolicy().waits_too_long(3600) and not RetryPolicy().waits_too_long(30)
    assert _parse_retry_after("nan") is None and _parse_retry_after("2.5") == 2.5 and _parse_retry_after("-4") == 0.0


# -- 25.5: a provider's key goes only to its own host, or where the user names a key variable --------------


KEYS = {
    "OPENAI_API_KEY": "sk-proj-OPENAI-SECRET-0123456789",
    "ANTHROPIC_API_KEY": "sk-ant-ANTHROPIC-SECRET-0123456789",
    "GEMINI_API_KEY": "AIzaGEMINI-SECRET-0123456789",
}


def sent_secrets(server) -> set[str]:
    out = set()
    for req in server.requests:
        blob = json.dumps([req.path, req.headers])
        out |= {name for name, value in KEYS.items() if value in blob}
    return out


# the direct transport speaks only the OpenAI protocol: the native Anthropic / Gemini paths go through litellm
@pytest.mark.parametrize(
    ("model", "openai_path", "transport"),
    [(m, True, t) for m in ("gpt-4o", "openai/test-model") for t in ("litellm", "direct")]
    + [("anthropic/claude-sonnet-4-6", False, "litellm"), ("gemini/gemini-2.5-flash", False, "litellm")],
)
def test_no_provider_key_goes_to_an_api_base_without_an_explicit_key_variable(
    elsewhere, monkeypatch, tmp_path, frames, model, openai_path, transport
):
    for name, value in KEYS.items():
        monkeypatch.setenv(name, value)
    with FakeOpenAIServer() as server:
        run(
            model,
            frames=frames[:1],
            api_base=server.url if openai_path else server.root_url,
            output=tmp_path / "a",
            transport=transport,
            **FAST,
        )
        assert server.requests and sent_secrets(server) == set()
        # named explicitly, that key (and only that one) goes there
        monkeypatch.setenv("MY_SERVER_KEY", "sk-my-own-server-key-0123456789")
        run(
            model,
            frames=frames[:1],
            api_base=server.url if openai_path else server.root_url,
            output=tmp_path / "b",
            transport=transport,
            api_key_env="MY_SERVER_KEY",
            **FAST,
        )
        later = server.requests[-1]
        assert "sk-my-own-server-key-0123456789" in json.dumps([later.path, later.headers])
        assert sent_secrets(server) == set()


def test_demo_with_an_api_base_sends_none_of_the_three_keys(elsewhere, monkeypatch, tmp_path):
    from lightemma.offline_demo import run_demo

    for name, value in KEYS.items():
        monkeypatch.setenv(name, value)
    with FakeOpenAIServer() as server:
        run_demo(tmp_path / "demo", scenes=1, keyframes=16, api_limit=1, api_base=server.url, log=lambda line: None)
        assert server.requests and sent_secrets(server) == set()


BASE_VARIABLE_CASES = [
    ("gpt-4o", "OPENAI_BASE_URL", "OPENAI_API_KEY"),
    ("gpt-4o", "OPENAI_API_BASE", "OPENAI_API_KEY"),
    ("anthropic/claude-sonnet-4-6", "ANTHROPIC_API_BASE", "ANTHROPIC_API_KEY"),
    ("anthropic/claude-sonnet-4-6", "ANTHROPIC_BASE_URL", "ANTHROPIC_API_KEY"),
    ("gemini/gemini-2.5-flash", "GEMINI_API_BASE", "GEMINI_API_KEY"),
]


@pytest.mark.parametrize(("model", "variable", "key"), BASE_VARIABLE_CASES, ids=[v for _, v, _ in BASE_VARIABLE_CASES])
def test_a_base_url_variable_of_the_environment_gets_the_key_only_when_declared_the_providers(
    elsewhere, monkeypatch, tmp_path, frames, model, variable, key
):
    """litellm, the OpenAI SDK and the batch adapters send a provider's calls and key to OPENAI_BASE_URL & co. when
    no --api-base is given: such a variable is refused unless it names a host declared the provider's own."""
    from lightemma.errors import UserError

    for name, value in KEYS.items():
        monkeypatch.setenv(name, value)
    with FakeOpenAIServer() as server:
        monkeypatch.setenv(variable, server.url if model == "gpt-4o" else server.root_url)
        with pytest.raises(UserError) as refused:
            run(model, frames=frames[:1], output=tmp_path / "a", **FAST)
        assert variable in str(refused.value) and "LIGHTEMMA_PROVIDER_HOSTS" in str(refused.value)
        assert "\n" not in str(refused.value) and not server.requests and not (tmp_path / "a").exists()
        if variable == "OPENAI_API_BASE":
            return  # read by litellm's files and batch calls, not by its chat calls: refused, and a declared one unused
        provider = model.split("/")[0] if "/" in model else "openai"
        monkeypatch.setenv(
            "LIGHTEMMA_PROVIDER_HOSTS", f"{provider}=127.0.0.1"
        )  # declared: that gateway is the provider
        result = run(model, frames=frames[:1], output=tmp_path / "b", **FAST)
        assert server.requests and sent_secrets(server) == {key}
    backend = json.loads((result.run_dir / "manifest.json").read_text())["backend"]
    assert backend["api_base_from_environment"].startswith(f"{variable}=http://127.0.0.1:")


def test_an_unset_key_variable_is_refused_in_one_line_and_plain_http_elsewhere_is_warned(monkeypatch):
    from lightemma.backends import create_backend
    from lightemma.errors import UserError

    monkeypatch.delenv("NOPE_KEY", raising=False)
    with pytest.raises(UserError, match="--api-key-env NOPE_KEY: the environment variable NOPE_KEY is not set"):
        create_backend("openai/m", api_base="http://127.0.0.1:9/v1", api_key_env="NOPE_KEY")
    monkeypatch.setenv("MY_KEY", "sk-abc-0123456789")
    far = create_backend("openai/m", api_base="http://192.0.2.7:8000/v1", api_key_env="MY_KEY")
    (notice,) = far.notices
    assert "plain http" in notice and "MY_KEY" in notice and "sk-abc" not in notice
    for quiet in (
        "http://127.0.0.1:8000/v1",
        "http://localhost:8000/v1",
        "http://[::1]:8000/v1",
        "https://192.0.2.7/v1",
        "http://127.1:8000/v1",
        "http://[::ffff:127.0.0.1]:8000/v1",
        "http://LOCALHOST.:8000/v1",
    ):  # this machine too
        assert create_backend("openai/m", api_base=quiet).notices == []
    for short in ("http://127.1:8000/v1", "http://2130706433:8000/v1", "http://127.000.000.001:8000/v1"):
        with pytest.raises(UserError, match="as 127.0.0.1 for --transport direct"):  # aiohttp refuses it at every call
            create_backend("openai/m", api_base=short, transport="direct")


@pytest.mark.parametrize(
    "price", [(float("inf"), 1.0), (1e400, 1.0), (2.0, float("nan")), (-1.0, 2.0), (2e6, 1.0), (True, 1.0)]
)
def test_a_price_that_is_no_price_is_refused_before_any_call(price):
    """--price 1e400 1 was taken: every frame's cost computed as inf, then dropped to unknown after the run."""
    from lightemma.backends import create_backend
    from lightemma.errors import UserError

    with pytest.raises(UserError, match="--price needs two numbers from 0 to 1e"):
        create_backend("openai/m", api_base="http://127.0.0.1:9/v1", price=price)
    assert create_backend("openai/m", api_base="http://127.0.0.1:9/v1", price=(2, 5.5)).price_given == (2, 5.5)


# -- 25.15: credentials in --api-base stay out of every record and message --------------------------------


@pytest.mark.parametrize("transport", ["litellm", "direct"])
def test_a_password_in_the_api_base_is_in_no_record_and_no_message(tmp_path, frames, capsys, transport):
    from lightemma.cli import main

    with FakeOpenAIServer(lambda req: Reply.error(400, "bad request at http://alice:hunter2pw@host")) as server:
        base = server.url.replace("http://", "http://alice:hunter2pw@")
        out = tmp_path / "out"
        code = main(
            [
                "run",
                "--model",
                "openai/test-model",
                "--api-base",
                base,
                "--dataroot",
                str(tmp_path / "none"),
                "--output",
                str(out),
                "--no-progress",
            ]
        )
        assert code == 2  # no dataset: refused, but the message must not show the password either
        from lightemma.errors import RunStopped

        with pytest.raises(RunStopped) as info:
            run(
                "openai/test-model",
                frames=frames,
                api_base=base,
                output=out,
                max_attempts=1,
                transport=transport,
                **FAST,
            )
    messages = capsys.readouterr().err + str(info.value)
    assert server.requests[0].headers["authorization"].startswith("Basic ")  # used to reach the server, not shown
    written = b"".join(p.read_bytes() for p in out.rglob("*") if p.is_file())
    assert "hunter2pw" not in messages and b"hunter2pw" not in written
    from lightemma.backends.retry import redact_url

    assert redact_url("https://h/v1?api_key=querysecret123&v=2") == "https://h/v1?api_key=***&v=2"
    (run_dir,) = [p.parent for p in out.rglob("manifest.json")]
    assert json.loads((run_dir / "manifest.json").read_text())["config"]["api_base"].startswith("http://***@127.0.0.1:")


# -- 25.4: a run directory never redirects keys or writes --------------------------------------------------


def refused_resume(run_dir, server, capsys) -> str:
    """``lightemma run --resume RUN_DIR`` (with the run's own endpoint and cache) refused: exit 2, one line, no
    traceback, nothing asked of the server; the line."""
    from lightemma.cli import main

    before = len(server.requests)
    assert main(["run", "--resume", str(run_dir), "--api-base", server.url, "--cache", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    assert len(server.requests) == before
    return err


LEFT_OUT = object()  # a setting deleted from the manifest


def crafted_run(tmp_path, frames, server, **changes):
    """A finished-but-incomplete run whose manifest config is then edited as someone else might have."""
    from lightemma.runs.store import FRAMES_FILE, update_manifest

    first = run("openai/gpt-4o", api_base=server.url, frames=frames, output=tmp_path / "out", cache=True, **FAST)
    path = first.run_dir / FRAMES_FILE
    path.write_bytes(b"".join(path.read_bytes().splitlines(keepends=True)[:1]))  # two frames left to do
    manifest = json.loads((first.run_dir / "manifest.json").read_text())
    config = {**manifest["config"], **changes}
    update_manifest(first.run_dir, config={k: v for k, v in config.items() if v is not LEFT_OUT})
    return first.run_dir


def test_resume_refuses_a_manifest_whose_endpoint_is_not_the_users(elsewhere, monkeypatch, tmp_path, frames, capsys):
    from lightemma.cli import main

    monkeypatch.setenv("OPENAI_API_KEY", KEYS["OPENAI_API_KEY"])
    with FakeOpenAIServer() as ours, FakeOpenAIServer() as theirs:
        run_dir = crafted_run(tmp_path, frames, ours, api_base=theirs.url, api_key_env="OPENAI_API_KEY")
        before = len(ours.requests)
        for extra in ([], ["--api-base", ours.url], ["--api-base", theirs.url, "--cache"]):
            assert main(["run", "--resume", str(run_dir), *extra, "--no-progress"]) == 2
            err = capsys.readouterr().err
            assert len(err.strip().splitlines()) == 1 and ("--api-base" in err or "--api-key-env" in err), err
        assert not theirs.requests and len(ours.requests) == before
        # the user's own word for both: the run goes on there, with the key the user named
        from lightemma.pipeline import resume

        resume(run_dir, frames=frames, api_base=theirs.url, api_key_env="OPENAI_API_KEY", cache=True, progress=False)
        assert theirs.requests and len(ours.requests) == before
        assert theirs.requests[0].headers["authorization"] == f"Bearer {KEYS['OPENAI_API_KEY']}"


@pytest.mark.parametrize("cache", ["ABS", "../../../escape.sqlite"])
def test_resume_refuses_a_manifest_cache_path_the_user_did_not_give(tmp_path, frames, capsys, cache):
    from lightemma.cli import main

    target = tmp_path / "elsewhere" / "evil.sqlite"
    with FakeOpenAIServer() as server:
        run_dir = crafted_run(tmp_path, frames, server, cache=str(target) if cache == "ABS" else cache)
        for extra in ([], ["--cache"]):
            assert main(["run", "--resume", str(run_dir), "--api-base", server.url, *extra, "--no-progress"]) == 2
            err = capsys.readouterr().err
            assert len(err.strip().splitlines()) == 1 and "--cache" in err, err
        assert (
            not target.exists()
            and not (tmp_path / "escape.sqlite").exists()
            and not list(tmp_path.parent.glob("escape*"))
        )
        assert len(read_run(run_dir).records) == 1
        # given on the command line, the path is the user's choice
        wanted = target if cache == "ABS" else (run_dir.parent.parent / cache).resolve()
        from lightemma.pipeline import resume

        resume(run_dir, frames=frames, api_base=server.url, cache=str(wanted), progress=False)
        assert wanted.exists() and len(read_run(run_dir).records) == 3


@pytest.mark.parametrize(
    ("changes", "words"),
    [
        ({"ray_address": "10.0.0.1:6379"}, "--ray-address"),
        ({"backend_options": {"trust_remote_code": True}}, "--trust-remote-code"),
        (
            {"backend_options": {"runtime_env": {"pip": ["evil-package"]}}},
            "'runtime_env': the run's {'pip': ['evil-package']}",
        ),
        (
            {"backend_options": {"attn_implementation": "someone/kernels"}},
            "'attn_implementation': the run's 'someone/kernels'",
        ),
    ],
)
def test_resume_refuses_a_manifest_that_chooses_where_the_model_runs_or_what_code_runs(
    tmp_path, frames, capsys, changes, words
):
    from lightemma.errors import UserError
    from lightemma.pipeline import resume

    with FakeOpenAIServer() as server:
        run_dir = crafted_run(tmp_path, frames, server, **changes)
        before = len(server.requests)
        err = refused_resume(run_dir, server, capsys)
        assert words in err and "does not choose" in err, err
        with pytest.raises(UserError, match="does not choose"):
            resume(run_dir, frames=frames, api_base=server.url, cache=True, progress=False)
        assert len(server.requests) == before and len(read_run(run_dir).records) == 1


def test_resume_refuses_options_it_takes_from_the_manifest_and_code_options_the_run_did_not_have(tmp_path, frames):
    from lightemma.errors import UserError
    from lightemma.pipeline import resume

    with FakeOpenAIServer() as server:
        run_dir = crafted_run(tmp_path, frames, server)
        with pytest.raises(UserError, match="did not load the model with trust_remote_code"):
            resume(
                run_dir,
                frames=frames,
                api_base=server.url,
                cache=True,
                backend_options={"trust_remote_code": True},
                progress=False,
            )
        with pytest.raises(UserError, match="takes batch_size from the run's manifest"):
            resume(
                run_dir,
                frames=frames,
                api_base=server.url,
                cache=True,
                backend_options={"batch_size": 4},
                progress=False,
            )
        assert len(read_run(run_dir).records) == 1


@pytest.mark.parametrize(
    ("changes", "words"),
    [
        ({"concurrency": "x"}, "config.concurrency is 'x', not a whole number"),
        ({"timeout": None}, "config.timeout is None"),
        ({"timeout": "soon"}, "config.timeout is 'soon'"),
        ({"dataset": [1]}, "config.dataset is [1], not an object"),
        ({"backend_options": ["x"]}, "config.backend_options is ['x'], not an object"),
        ({"prompt_set": ["x"]}, "config.prompt_set"),
        ({"backend_options": {"trust_remote_code": "yes"}}, "trust_remote_code is 'yes', not true or false"),
        ({"ray_address": 0}, "ray_address is 0, not an address"),
        ({"backend_options": {"batch_size": "8"}}, "cannot build the run's backend (TypeError"),
        ({"model": ["gpt-4o"]}, "config.model is ['gpt-4o'], not text"),
        ({"timeout": -1}, "config.timeout is -1, not a number greater than 0"),
        ({"temperature": -1}, "config.temperature is -1, not a number of at least 0"),
        ({"cache": True}, "config.cache is True, not text"),
        ({"speed_range": [5, 1]}, "config.speed_range is [5, 1], not [low, high]"),
        ({"dataset": {"scenes": [1]}}, "config.dataset.scenes is [1], not a list of scene names"),
        ({"dataset": {"sample": {"seed": 0}}}, "config.dataset.sample"),
        ({"batch": -2.5}, "config.batch is -2.5, not true or false"),
        # the trial's: left-out settings, numbers beyond a float, and values that would wait or retry without end
        *[
            ({name: LEFT_OUT}, f"config has no {name}")
            for name in ("timeout", "max_retries", "backoff_base", "rpm", "tpm")
        ],
        ({"timeout": 10**400}, "config.timeout is a whole number of 401 digits, not a finite number"),
        ({"speed_range": [-(10**400), 10**400]}, "config.speed_range is [-1000"),
        ({"rpm": 1e-300}, "config.rpm is 1e-300, not between 1 and 1e+09"),
        ({"tpm": 1e-300}, "config.tpm is 1e-300, not between 10 and 1e+12"),
        ({"timeout": 1e-300}, "config.timeout is 1e-300, not between 0.001 and 86400"),
        ({"timeout": 1e308}, "config.timeout is 1e+308, not between"),
        ({"max_attempts": 10**9}, "config.max_attempts is 1000000000, not between 1 and 100"),
        ({"max_retries": 10**400}, "config.max_retries is a whole number of 401 digits, not between 0 and 100"),
        ({"cache": "runs/x\x00y"}, "not text without NUL characters"),
    ],
)
def test_a_hand_edited_manifest_is_refused_in_one_line_never_a_traceback(tmp_path, frames, capsys, changes, words):
    with FakeOpenAIServer() as server:
        run_dir = crafted_run(tmp_path, frames, server, **changes)
        assert words in refused_resume(run_dir, server, capsys)


@pytest.mark.slow
@pytest.mark.parametrize("how", ["deep manifest", "frame_ids to /dev/zero", "frame_ids a FIFO"])
def test_a_run_directory_file_that_is_deep_endless_or_a_pipe_is_refused_in_one_line(tmp_path, frames, capsys, how):
    from lightemma.cli import main
    from lightemma.pipeline import resume
    from lightemma.runs.store import FRAME_IDS_FILE, MANIFEST_FILE

    with FakeOpenAIServer() as server:
        run_dir = crafted_run(tmp_path, frames, server)
        before = len(server.requests)
        if how == "deep manifest":
            (run_dir / MANIFEST_FILE).write_text("[" * 200_000 + "]" * 200_000)
        elif how == "frame_ids a FIFO":
            (run_dir / FRAME_IDS_FILE).unlink()
            os.mkfifo(run_dir / FRAME_IDS_FILE)  # nobody writes it: a read would wait forever
        else:
            (run_dir / FRAME_IDS_FILE).unlink()
            (run_dir / FRAME_IDS_FILE).symlink_to("/dev/zero")  # a read would fill the memory
        if how == "deep manifest":
            done = subprocess.run(
                [
                    sys.executable,
                    "-m",
                    "lightemma",
                    "run",
                    "--resume",
                    str(run_dir),
                    "--api-base",
                    server.url,
                    "--cache",
                    "--no-progress",
                ],
                capture_output=True,
                text=True,
                env=env(),
                timeout=120,
            )
            assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr
            assert len(done.stderr.strip().splitlines()) == 1 and "nested too deeply" in done.stderr, done.stderr
        else:  # a run of frames passed in memory: resumed from Python
            from lightemma.errors import RunStoreError

            with pytest.raises(RunStoreError, match="frame_ids.txt is not a regular file"):
                resume(run_dir, frames=frames, api_base=server.url, cache=True, progress=False)
        assert len(server.requests) == before  # nothing asked
        capsys.readouterr()
        code = main(["evaluate", str(run_dir)])  # named and skipped, or refused: in one line, never read without end
        err = capsys.readouterr().err
        assert code in (0, 1, 2) and "Traceback" not in err and str(run_dir) in err, (code, err)


def test_a_resume_takes_how_long_and_how_fast_to_ask_and_records_it(tmp_path, frames, capsys):
    from lightemma.cli import main
    from lightemma.runs.store import read_manifest

    with FakeOpenAIServer() as server:
        run_dir = crafted_run(tmp_path, frames, server)
        assert (
            main(
                [
                    "run",
                    "--resume",
                    str(run_dir),
                    "--api-base",
                    server.url,
                    "--cache",
                    "--timeout",
                    "inf",
                    "--no-progress",
                ]
            )
            == 2
        )
        assert "--timeout must be a finite number, got inf" in capsys.readouterr().err
        assert (
            main(
                [
                    "run",
                    "--resume",
                    str(run_dir),
                    "--api-base",
                    server.url,
                    "--cache",
                    "--rpm",
                    "1e-300",
                    "--no-progress",
                ]
            )
            == 2
        )
        assert "--rpm must be between 1 and 1e+09, got 1e-300" in capsys.readouterr().err
        from lightemma.pipeline import resume

        resume(run_dir, frames=frames, api_base=server.url, cache=True, timeout=33, rpm=600, progress=False)
    session = read_manifest(run_dir)["sessions"][-1]
    assert (session["kind"], session["timeout"], session["rpm"]) == ("resume", 33.0, 600.0)
    assert read_manifest(run_dir)["config"]["timeout"] == 10.0  # the run's own setting stays as it was


def test_replies_too_large_on_frame_after_frame_stop_the_run_naming_the_limit(tmp_path, frames):
    from lightemma.backends.openai_http import MAX_BODY_BYTES
    from lightemma.errors import RunStopped

    with FakeOpenAIServer(lambda req: Reply(bulk=MAX_BODY_BYTES + 1)) as server:
        with pytest.raises(RunStopped) as stopped:
            run(
                "openai/test-model", frames=frames, api_base=server.url, output=tmp_path / "out", max_attempts=1, **FAST
            )
    assert "larger than the 8 MiB lightemma reads" in str(stopped.value) and stopped.value.cause == "invalid-response"


@pytest.mark.slow
def test_a_local_run_with_trust_remote_code_resumes_only_with_it_again(tmp_path, synth_root, tiny_qwen, capsys):
    from lightemma.cli import main
    from lightemma.runs.store import FRAMES_FILE, read_manifest

    out = tmp_path / "out"
    args = [
        "--dataroot",
        str(synth_root),
        "--version",
        "v1.0-mini",
        "--split",
        "all",
        "--limit",
        "2",
        "--max-tokens",
        "4",
        "--max-attempts",
        "1",
        "--output",
        str(out),
        "--no-progress",
    ]
    assert (
        main(["run", "--model", str(tiny_qwen), "--backend", "hf", "--device", "cpu", "--trust-remote-code", *args])
        == 1
    )
    (run_dir,) = run_dirs(out)
    assert read_manifest(run_dir)["config"]["backend_options"]["trust_remote_code"] is True
    path = run_dir / FRAMES_FILE
    path.write_bytes(b"".join(path.read_bytes().splitlines(keepends=True)[:1]))  # one frame left to do
    capsys.readouterr()
    assert main(["run", "--resume", str(run_dir), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "--trust-remote-code" in err, err
    assert (
        main(["run", "--resume", str(run_dir), "--trust-remote-code", "--no-progress"]) == 1
    )  # random weights: no valid frame
    assert len(read_run(run_dir).records) == 2


# -- 25.10: SIGTERM and SIGHUP stop a run like Ctrl-C ------------------------------------------------------


def wait_for(predicate, seconds: float, what: str) -> None:
    deadline = time.monotonic() + seconds
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.05)


def run_dirs(out: Path) -> list[Path]:
    """The run directories under ``out`` (OUT/MODEL/RUN_ID) while a run may be creating one: a hidden temporary
    folder is never entered (it is renamed away under a scan: rglob raised FileNotFoundError on a loaded machine)."""
    found = []
    for model in sorted(out.glob("*")) if out.is_dir() else []:
        try:
            runs = [d for d in model.iterdir() if not d.name.startswith(".")] if not model.name.startswith(".") else []
        except (FileNotFoundError, NotADirectoryError):
            continue
        found += [d for d in sorted(runs) if (d / "manifest.json").exists()]
    return found


@pytest.mark.slow
@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGHUP])
def test_sigterm_and_sighup_stop_a_run_like_ctrl_c(tmp_path, synth_root, signum):
    from lightemma.runs.store import LOCK_PID_FILE, read_manifest

    out = tmp_path / "out"
    with FakeOpenAIServer(latency=0.2) as server:
        proc = subprocess.Popen(
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
            env=env(),
            text=True,
        )
        try:
            wait_for(
                lambda: any(
                    (d / "frames.jsonl").exists() and (d / "frames.jsonl").stat().st_size for d in run_dirs(out)
                ),
                60,
                "a first frame",
            )
            proc.send_signal(signum)
            _, err = proc.communicate(timeout=20)
        finally:
            if proc.poll() is None:
                proc.kill()
    assert proc.returncode == 128 + signum, err
    name = signal.Signals(signum).name
    assert f"interrupted by {name}" in err and "--resume" in err and "Traceback" not in err, err
    (run_dir,) = run_dirs(out)
    assert not (run_dir / LOCK_PID_FILE).exists()
    (session,) = read_manifest(run_dir)["sessions"]
    assert session["interrupted"] is True and session["signal"] == name and session["wall_seconds"] > 0


# -- 25.2: a local generate that hangs neither freezes the run nor survives Ctrl-C -------------------------


HANG = """
import sys, threading
from lightemma.backends import hf
hf.HFBackend._generate = lambda self, requests: threading.Event().wait()  # never returns, ignores every criterion
from lightemma.cli import main
sys.exit(main(sys.argv[1:]))
"""


@pytest.fixture(scope="module")
def tiny_qwen(tmp_path_factory):
    from tests.support.local_models import build_tiny_model

    return build_tiny_model("qwen2_vl", tmp_path_factory.mktemp("qwen2_vl_hang"))


def hf_run(tiny_qwen, synth_root, out, *extra):
    return subprocess.Popen(
        [
            sys.executable,
            "-c",
            HANG,
            "run",
            "--model",
            str(tiny_qwen),
            "--backend",
            "hf",
            "--device",
            "cpu",
            "--dataroot",
            str(synth_root),
            "--version",
            "v1.0-mini",
            "--split",
            "all",
            "--limit",
            "2",
            "--output",
            str(out),
            "--no-progress",
            *extra,
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env=env(),
        text=True,
    )


@pytest.mark.slow
def test_a_hung_local_generate_stops_the_run_at_the_timeout_resumable(tmp_path, synth_root, tiny_qwen):
    from lightemma.runs.store import LOCK_PID_FILE, read_manifest

    out = tmp_path / "out"
    proc = hf_run(tiny_qwen, synth_root, out, "--timeout", "1")
    try:
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 2, err
    lines = [line for line in err.splitlines() if "error" in line]
    assert len(lines) == 1 and "did not finish a batch within --timeout 1 s" in lines[0] and "--resume" in lines[0], err
    (run_dir,) = run_dirs(out)
    assert not (run_dir / LOCK_PID_FILE).exists()
    assert read_manifest(run_dir)["sessions"][0]["stopped"]["cause"] == "local-timeout"


@pytest.mark.slow
@pytest.mark.parametrize("twice", [False, True])
def test_ctrl_c_stops_a_hung_local_generate_and_a_second_one_exits_at_once(tmp_path, synth_root, tiny_qwen, twice):
    from lightemma.runs.store import LOCK_PID_FILE

    out = tmp_path / "out"
    proc = hf_run(tiny_qwen, synth_root, out, "--timeout", "600")
    try:
        wait_for(lambda: any((d / LOCK_PID_FILE).exists() for d in run_dirs(out)), 120, "the run to start")
        time.sleep(1.0)  # the worker is now inside the hung generate
        proc.send_signal(signal.SIGINT)
        start = time.monotonic()
        if twice:
            time.sleep(0.5)
            proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=30)
        elapsed = time.monotonic() - start
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, err
    assert elapsed < (3 if twice else 15), elapsed
    assert "--resume" in err
    (run_dir,) = run_dirs(out)
    assert not (run_dir / LOCK_PID_FILE).exists()


@pytest.mark.slow
def test_every_local_batch_past_the_timeout_stops_in_one_line_naming_the_resume_with_a_longer_wait(
    tmp_path, synth_root, tiny_qwen
):
    """One line (no stray tracebacks after it: tests/unit/backends/test_batching.py), and the fix it names works on a resume."""
    out = tmp_path / "out"
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "lightemma",
            "run",
            "--model",
            str(tiny_qwen),
            "--backend",
            "hf",
            "--device",
            "cpu",
            "--dataroot",
            str(synth_root),
            "--version",
            "v1.0-mini",
            "--split",
            "all",
            "--limit",
            "6",
            "--timeout",
            "0.001",
            "--max-tokens",
            "8",
            "--output",
            str(out),
            "--no-progress",
        ],
        capture_output=True,
        text=True,
        env=env(),
        timeout=300,
    )
    lines = [
        line for line in done.stderr.splitlines() if line.strip() and not line.startswith("Loading weights")
    ]  # transformers'
    assert done.returncode == 2 and "Traceback" not in done.stderr and "never retrieved" not in done.stderr, done.stderr
    assert (
        "every batch runs past --timeout 0.001 s" in lines[-1]
        and "--resume" in lines[-1]
        and "--timeout SECONDS" in lines[-1]
    )
    assert len(lines) == 3, lines  # the frames, the run directory, the stop
    (run_dir,) = run_dirs(out)
    again = subprocess.run(
        [sys.executable, "-m", "lightemma", "run", "--resume", str(run_dir), "--timeout", "600", "--no-progress"],
        capture_output=True,
        text=True,
        env=env(),
        timeout=300,
    )
    assert again.returncode == 1, again.stderr  # finished (random weights: no valid frame), with the longer wait
    assert len(read_run(run_dir).records) == 6


@pytest.mark.slow
def test_a_local_generate_past_the_timeout_fails_its_batch_as_timeout(tiny_qwen, tmp_path):
    from PIL import Image

    from lightemma.backends import ChatRequest, GenerationParams
    from lightemma.backends.hf import HFBackend

    image = tmp_path / "cam.jpg"
    Image.new("RGB", (32, 32), (10, 20, 30)).save(image)
    backend = HFBackend(str(tiny_qwen), device="cpu", timeout=0.5)
    request = ChatRequest(
        text="describe",
        stage="scene",
        frame_id="s/0",
        image_path=str(image),
        params=GenerationParams(max_tokens=1_000_000),
    )  # babble: it would never end
    start = time.monotonic()
    (result,) = asyncio.run(backend.generate([request]))
    assert time.monotonic() - start < 10
    assert result.error == "Timeout" and result.text is None
    asyncio.run(backend.aclose())


# -- 25.13: a failure tied to some frames does not stop the run ----------------------------------------------


def scenes_in_order(tmp_path, first: int, second: int):
    """Frames of scene A (``first`` of them) and then scene B, in that order (as a dataset lists them)."""
    import dataclasses

    frames = make_frames(tmp_path, first + second)
    out = []
    for i, f in enumerate(frames):
        scene = "scene-A" if i < first else "scene-B"
        out.append(dataclasses.replace(f, scene_name=scene, frame_id=f"{scene}/{f.sample_token}"))
    return out


def test_a_provider_rejecting_one_scenes_images_does_not_stop_the_run(tmp_path):
    from tests.support.memframes import FrameIndex

    frames = scenes_in_order(tmp_path, 5, 3)
    index = FrameIndex(frames)

    def script(req):
        if index(req) < 5:
            return Reply.error(400, "Invalid image: the image could not be processed")
        return default_reply(req)

    with FakeOpenAIServer(script) as server:
        result = run(
            "openai/test-model",
            frames=frames,
            api_base=server.url,
            output=tmp_path / "out",
            concurrency=1,
            max_attempts=2,
            **FAST,
        )
    records = read_run(result.run_dir).records
    assert [records[f.frame_id]["status"] for f in frames] == ["failed"] * 5 + ["ok"] * 3
    assert all(records[f.frame_id]["error"] == "BadRequestError" for f in frames[:5])


def test_the_same_rejection_across_scenes_still_stops_the_run(tmp_path):
    from lightemma.errors import RunStopped

    frames = scenes_in_order(tmp_path, 4, 3)
    with FakeOpenAIServer(lambda req: Reply.error(400, "max_tokens is too large")) as server:
        with pytest.raises(RunStopped, match="every request is rejected the same way"):
            run(
                "openai/test-model",
                frames=frames,
                api_base=server.url,
                output=tmp_path / "out",
                concurrency=1,
                max_attempts=2,
                **FAST,
            )
        assert len(server.requests) <= 2 * 5  # stopped at the first frame of the second scene


# -- 25.8: a response cache that cannot write is reported once; the run goes on ----------------------------


def test_a_locked_response_cache_is_reported_in_one_line_and_the_run_goes_on_uncached(tmp_path, frames, monkeypatch):
    import sqlite3

    from lightemma import cache as cache_module
    from lightemma.runs.store import read_manifest

    monkeypatch.setattr(cache_module, "BUSY_TIMEOUT", 0.2)
    path = tmp_path / "out" / "cache.sqlite"
    holder: list[sqlite3.Connection] = []
    lines: list[str] = []

    def script(req):
        if not holder:  # another writer takes the database once the run has it open
            db = sqlite3.connect(path, isolation_level=None, check_same_thread=False)
            db.execute("BEGIN EXCLUSIVE")
            holder.append(db)
        return default_reply(req)

    with FakeOpenAIServer(script) as server:
        result = run(
            "openai/test-model",
            frames=frames,
            api_base=server.url,
            output=tmp_path / "out",
            cache=True,
            log=lines.append,
            **FAST,
        )
    holder[0].close()
    warnings = [line for line in lines if "response cache" in line]
    assert len(warnings) == 1 and "database is locked" in warnings[0] and "without caching" in warnings[0], lines
    assert result.summary["ok"] == len(frames)
    assert "database is locked" in read_manifest(result.run_dir)["sessions"][0]["cache_failure"]


# -- 25.9: a response body has a size limit -----------------------------------------------------------------


BODY_LIMIT_CASES = [  # (model, transport, key variable): every client a reply can reach lightemma through
    ("openai/test-model", "litellm", None),
    ("openai/test-model", "direct", None),
    ("anthropic/claude-sonnet-4-6", "litellm", "ANTHROPIC_API_KEY"),
    ("gemini/gemini-2.5-flash", "litellm", "GEMINI_API_KEY"),
]


@pytest.mark.parametrize(
    ("model", "transport", "variable"), BODY_LIMIT_CASES, ids=[f"{m.split('/')[0]}-{t}" for m, t, _ in BODY_LIMIT_CASES]
)
@pytest.mark.parametrize("length", ["declared", "chunked"])
def test_a_huge_response_body_fails_the_call_and_is_never_read_whole(monkeypatch, model, transport, variable, length):
    from lightemma.backends import ChatRequest, create_backend
    from lightemma.backends.openai_http import MAX_BODY_BYTES
    from lightemma.backends.retry import RetryPolicy
    from tests.support.fake_openai import SCENE_TEXT

    if variable:
        monkeypatch.setenv(variable, "native-test-key-0123456789")
    huge = Reply(bulk=8 * MAX_BODY_BYTES, chunked=length == "chunked")  # 64 MiB, declared or not
    with FakeOpenAIServer([huge, Reply(SCENE_TEXT)]) as server:
        base = server.url if model.startswith("openai/") else server.root_url
        backend = create_backend(
            model, api_base=base, transport=transport, retry=RetryPolicy(max_retries=2, base=0.01, cap=0.05)
        )

        async def two():
            req = ChatRequest(text="describe", stage="scene", frame_id="s/a")
            return [(await backend.generate([req]))[0], (await backend.generate([req]))[0]]

        big, small = asyncio.run(two())
        asyncio.run(backend.aclose())
    assert big.error == "ResponseTooLargeError" and big.retries == 0 and "bytes" in big.error_message, big
    assert small.ok and small.text == SCENE_TEXT and len(server.requests) == 2
    # the client stopped reading: what the server could write is the limit plus the sockets' buffers, not 64 MiB
    assert len(server.bulk_sent) == 1 and server.bulk_sent[0] < 4 * MAX_BODY_BYTES, server.bulk_sent


@pytest.mark.parametrize(
    ("model", "transport", "variable"), BODY_LIMIT_CASES, ids=[f"{m.split('/')[0]}-{t}" for m, t, _ in BODY_LIMIT_CASES]
)
def test_the_limit_is_on_the_decoded_body_a_compressed_bomb_fails_and_normal_compressed_replies_read(
    monkeypatch, model, transport, variable
):
    """A 64 MiB body gzipped to ~64 KB fails at the limit (httpx inflated it whole before); gzip, deflate and raw deflate
    replies of normal size read as before; an encoding lightemma did not ask for fails unread."""
    from lightemma.backends import ChatRequest, create_backend
    from lightemma.backends.openai_http import MAX_BODY_BYTES
    from lightemma.backends.retry import RetryPolicy
    from tests.support.fake_openai import SCENE_TEXT

    if variable:
        monkeypatch.setenv(variable, "native-test-key-0123456789")
    bomb = Reply(bulk=8 * MAX_BODY_BYTES, encoding="gzip")
    replies = [
        bomb,
        Reply(SCENE_TEXT, encoding="gzip"),
        Reply(SCENE_TEXT, encoding="deflate"),
        Reply(SCENE_TEXT, encoding="raw-deflate"),
        Reply(SCENE_TEXT, encoding="br"),
        Reply(SCENE_TEXT, encoding="gzip-members"),
        Reply(SCENE_TEXT, encoding="gzip", trailing=16),
        Reply(SCENE_TEXT, encoding="gzip", trailing=MAX_BODY_BYTES + 1),
        Reply(SCENE_TEXT, encoding="gzip-cut"),
        Reply(SCENE_TEXT, encoding="gzip-corrupt"),
    ]
    with FakeOpenAIServer(replies) as server:
        base = server.url if model.startswith("openai/") else server.root_url
        backend = create_backend(
            model, api_base=base, transport=transport, retry=RetryPolicy(max_retries=0, base=0.01, cap=0.05)
        )

        async def ask_all():
            req = ChatRequest(text="describe", stage="scene", frame_id="s/a")
            return [(await backend.generate([req]))[0] for _ in replies]

        got = asyncio.run(ask_all())
        asyncio.run(backend.aclose())
    assert server.bulk_sent[0] < MAX_BODY_BYTES  # the bomb is small on the wire
    assert got[0].error == "ResponseTooLargeError" and got[0].text is None, got[0]
    assert [r.text for r in got[1:4]] == [SCENE_TEXT] * 3, got[1:4]
    assert got[4].error == "ResponseEncodingError" and "'br'" in got[4].error_message, got[4]
    assert {r.headers.get("accept-encoding") for r in server.requests} == {"gzip, deflate"}
    assert got[7].error == "ResponseTooLargeError", got[7]  # bytes after the end count: never read without end
    assert got[5].text == SCENE_TEXT  # two gzip members
    if transport == "direct":  # aiohttp inflates by its own rules: stricter after the end, laxer on a cut-off stream
        assert got[6].error == "ResponseEncodingError" and "not valid gzip" in got[6].error_message, got[6]
        assert got[8].text is None and got[8].error in ("ResponseEncodingError", "APIError"), got[8]  # never an answer
        assert got[9].error == "ResponseEncodingError" and "not valid gzip" in got[9].error_message, got[9]
        return
    assert got[6].text == SCENE_TEXT  # a few bytes after the end: dropped
    assert [(r.error, "not valid gzip" in (r.error_message or "")) for r in got[8:]] == [
        ("ResponseEncodingError", True)
    ] * 2


@pytest.mark.parametrize("transport", ["litellm", "direct"])
def test_half_an_emoji_in_an_answer_becomes_a_replacement_character_and_the_chain_goes_on(tmp_path, frames, transport):
    """A provider's JSON may escape a lone surrogate ("\\ud83d"); UTF-8 cannot hold it, so neither the record nor the
    next stage's request could: it arrives as U+FFFD."""
    scene = "A wet road \ud83d ahead; a van is parked on the right and the light is green."

    def script(req):
        return Reply(scene) if req.stage == "scene" else default_reply(req)

    with FakeOpenAIServer(script) as server:
        result = run(
            "openai/test-model",
            frames=frames[:1],
            api_base=server.url,
            output=tmp_path / "out",
            transport=transport,
            **FAST,
        )
    (record,) = read_run(result.run_dir).records.values()
    assert record["status"] == "ok" and record["scene_text"] == scene.replace("\ud83d", "\ufffd")
    assert [r.stage for r in server.requests] == ["scene", "intent", "actions"]
    assert "\ufffd" in server.requests[1].text


# -- 22.5: --api-base checked at once ----------------------------------------------------------------------


def closed_port() -> int:
    import socket

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]  # closed again: nothing listens there


@pytest.mark.parametrize(
    ("base", "words"),
    [
        ("localhost:8000/v1", "needs a scheme"),
        ("http://127.0.0.1:99999/v1", "usable URL"),
        ("http://127.0.0.1:PORT/v1", "cannot connect"),
        ("alice:hunter2pw@127.0.0.1:1/v1", "needs a scheme"),
        ("http:/alice:hunter2pw@127.0.0.1:1/v1", "needs a scheme"),
        ("http//alice:hunter2pw@127.0.0.1:1/v1", "needs a scheme"),
    ],
)
def test_a_bad_or_dead_api_base_is_refused_in_one_line_before_any_work(tmp_path, synth_root, capsys, base, words):
    from lightemma.cli import main

    base = base.replace("PORT", str(closed_port()))
    code = main(
        [
            "run",
            "--model",
            "openai/test-model",
            "--api-base",
            base,
            "--dataroot",
            str(synth_root),
            "--version",
            "v1.0-mini",
            "--split",
            "all",
            "--limit",
            "2",
            "--output",
            str(tmp_path / "out"),
            "--no-progress",
        ]
    )
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1 and words in err, err
    assert "hunter2pw" not in err  # a password in a URL without a scheme is still a password
    assert not (tmp_path / "out").exists()  # before any work: no run directory, no retries against a dead host


# -- 22.5: a model served from --api-base is that server's: its protocol, no list price, no registry GPUs -------


def test_a_registry_model_of_another_provider_at_an_api_base_speaks_openai_and_has_no_list_price(
    elsewhere, monkeypatch, tmp_path, frames
):
    monkeypatch.setenv("ANTHROPIC_API_KEY", KEYS["ANTHROPIC_API_KEY"])
    with FakeOpenAIServer() as server:
        plain = run("claude-4.6-sonnet", frames=frames[:2], api_base=server.url, output=tmp_path / "a", **FAST)
        priced = run("gpt-4o", frames=frames[:2], api_base=server.url, output=tmp_path / "b", price=(1.0, 2.0), **FAST)
    first = server.requests[0]
    assert first.protocol == "openai" and first.body["model"] == "claude-sonnet-4-6" and sent_secrets(server) == set()
    records = list(read_run(plain.run_dir).records.values())
    assert all(r["status"] == "ok" and r["cost_cents"] is None for r in records)  # not Anthropic's list price
    assert plain.manifest["model_info"]["input_usd_per_mtok"] is None and "unknown" in plain.manifest["backend"]["cost"]
    for record in read_run(priced.run_dir).records.values():  # --price: 3 calls of 1000 in, 50 out
        assert record["cost_cents"] == pytest.approx(3 * (1000 * 1.0 + 50 * 2.0) / 1e6 * 100)


def test_a_local_model_served_from_an_api_base_shows_no_registry_gpu_count_unless_given(elsewhere, tmp_path, frames):
    from lightemma.evaluation.manifest import _gpus
    from lightemma.models.catalog import lookup

    assert lookup("qwen-2.5-vl-7b").gpus >= 1  # the paper's hardware
    with FakeOpenAIServer() as server:
        plain = run("qwen-2.5-vl-7b", frames=frames[:1], api_base=server.url, output=tmp_path / "a", **FAST)
        given = run("qwen-2.5-vl-7b", frames=frames[:1], api_base=server.url, output=tmp_path / "b", gpus=4, **FAST)
    assert _gpus(plain.manifest) is None and _gpus(given.manifest) == 4


STARTUP_WINDOW = r"""
import sys, time
import lightemma.pipeline.runner as runner
original = runner._session
def slow(*args, **kwargs):  # the run directory exists, the session's own signal handlers are not in place yet
    print("window", file=sys.stderr, flush=True)
    time.sleep(60)
    return original(*args, **kwargs)
runner._session = slow
from lightemma.cli import main
sys.exit(main(sys.argv[1:]))
"""


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP])
def test_a_signal_before_the_first_frame_is_one_line_naming_the_resume_and_leaves_no_lock(tmp_path, synth_root, sig):
    """SIGTERM 3 s into a run (loading, the backend, the run directory) killed it silently: no line, .lock.pid and a
    temporary manifest left, the session not marked."""
    from lightemma.runs.store import LOCK_PID_FILE

    out = tmp_path / "out"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-c",
            STARTUP_WINDOW,
            "run",
            "--model",
            "baseline:cv",
            "--dataroot",
            str(synth_root),
            "--version",
            "v1.0-mini",
            "--split",
            "all",
            "--output",
            str(out),
            "--no-progress",
        ],
        stderr=subprocess.PIPE,
        text=True,
        env=env(),
    )
    before = []
    for line in proc.stderr:  # the frames and run directory lines, then the window
        if line.strip() == "window":
            break
        before.append(line)
    proc.send_signal(sig)
    err = "".join(before) + proc.communicate(timeout=60)[1]
    assert proc.returncode == 128 + sig, err
    lines = [line for line in err.splitlines() if "interrupted" in line]
    assert len(lines) == 1 and f"interrupted by {signal.Signals(sig).name}" in lines[0] and "--resume" in lines[0], err
    assert "Traceback" not in err
    (run_dir,) = run_dirs(out)
    assert not (run_dir / LOCK_PID_FILE).exists() and not list(run_dir.glob(".*.tmp"))


def test_a_frame_record_no_reader_would_read_stops_the_run_and_is_never_written(tmp_path, frames, monkeypatch):
    """Found by trial: a 60 MiB answer made a 943 MB frames.jsonl line, which every reader skips unread — while the
    run summed up 'ok' and exited 0 with the frame missing. A record over the line limit stops the run instead."""
    from lightemma.errors import RunStopped
    from lightemma.runs import store

    monkeypatch.setattr(store, "MAX_LINE_BYTES", 20_000)
    long_scene = lambda req: Reply("A road. " * 4000) if req.stage == "scene" else default_reply(req)  # noqa: E731
    with FakeOpenAIServer(long_scene) as server:
        with pytest.raises(RunStopped) as stopped:
            run("openai/test-model", frames=frames[:2], output=tmp_path, api_base=server.url, concurrency=1, **FAST)
    assert stopped.value.cause == "record-too-large" and stopped.value.error == "RecordTooLargeError"
    first = str(stopped.value).splitlines()[0]
    assert "over the 20,000 a line of frames.jsonl may be" in first and "--max-tokens" in first, first
    assert (stopped.value.run_dir / "frames.jsonl").read_bytes() == b""  # nothing half-written, nothing to skip
