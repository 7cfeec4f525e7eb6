"""Runs that no provider, file or signal can hang, crash or turn against the user (issue 25, and 22.5).

Every test drives the real code against loopback servers (tests/fake_openai.py), crafted run
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
from fake_openai import INTENT_TEXT, FakeOpenAIServer, Reply, default_reply
from memframes import make_frames

from lightemma.pipeline import run
from lightemma.prompts import load_prompt_set
from lightemma.runs.store import read_run

FAST = dict(backoff_base=0.01, backoff_cap=0.05, timeout=10.0, progress=False)
ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture
def frames(tmp_path):
    return make_frames(tmp_path, 3)


def env(**extra: str) -> dict[str, str]:
    """The environment of a lightemma subprocess: this checkout's code, no network for HF or litellm."""
    out = {k: v for k, v in os.environ.items() if not k.endswith("_API_KEY")}
    out.update(PYTHONPATH=str(ROOT / "python") + os.pathsep + str(ROOT / "tests"), HF_HUB_OFFLINE="1",
               LITELLM_LOCAL_MODEL_COST_MAP="True", PYTHONUNBUFFERED="1", **extra)
    return out


# -- 25.14: a model's text is data, never a template --------------------------------------------------


def test_placeholders_in_a_models_answer_are_not_expanded_in_the_next_prompt():
    ps = load_prompt_set()
    scene = "a sign reads {intent} and {history} and {speeds}"
    intent = ps.render("intent", scene=scene, history="HIST", speeds="S", curvatures="C")
    assert scene in intent and "HIST" in intent  # the template's own {history} is filled, the scene's is not
    actions = ps.render("actions", scene=scene, intent="go {scene} {curvatures}", history="HIST", speeds="S", curvatures="C")
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

    replies = [Reply(status=429, headers={"Retry-After": after}, body={"error": {"message": "quota", "type": "rate_limit_exceeded"}})]
    with FakeOpenAIServer(replies) as server:
        start = time.monotonic()
        with pytest.raises(RunStopped) as info:
            run("openai/test-model", frames=frames, api_base=server.url, output=tmp_path / "out", concurrency=1,
                transport=transport, **FAST)
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
