"""Format-proof and cache-aware requests against the loopback server: structured answers, the identical
leading image, Anthropic cache breakpoints, the conversation chain, cached tokens and what they cost."""

import json

import numpy as np
import pytest

from lightemma.backends.structured import ACTIONS_SCHEMA, MAGNITUDE
from lightemma.cli import main as cli_main
from lightemma.errors import UserError
from lightemma.evaluation import evaluate_runs
from lightemma.evaluation.stats import Resampling
from lightemma.pipeline import run
from lightemma.prompts import load_prompt_set
from lightemma.runs.store import read_run
from tests.support.fake_openai import GOOD_ACTIONS, GOOD_ACTIONS_JSON, FakeOpenAIServer, Reply, default_reply
from tests.support.memframes import FrameIndex, make_frames

FAST = dict(backoff_base=0.01, backoff_cap=0.05, timeout=10.0, progress=False)
KEY = "native-test-key-0123456789"
NATIVE = {"anthropic": "ANTHROPIC_API_KEY", "gemini": "GEMINI_API_KEY"}
TRANSPORTS = pytest.mark.parametrize("transport", ["litellm", "direct"])


@pytest.fixture
def frames(tmp_path):
    return make_frames(tmp_path, 3)


@pytest.fixture
def camera_frames(tmp_path):
    """Frames with 1600 × 900 images: an image alone passes the providers' 1024-token cache minimum."""
    return make_frames(tmp_path, 3, image_size=(1600, 900))


def api_base(server, model):
    return server.url if model.startswith("openai/") else server.root_url


def records(result):
    return read_run(result.run_dir).records


def by_stage(server):
    out = {}
    for req in server.requests:
        out.setdefault(req.stage, []).append(req)
    return out


# -- structured answers ----------------------------------------------------------------------------


@TRANSPORTS
def test_stage_3_asks_for_the_actions_schema_and_the_json_answer_is_parsed_as_json(tmp_path, frames, transport):
    with FakeOpenAIServer() as server:
        result = run(
            "openai/gpt-4o",
            api_base=server.url,
            frames=frames,
            output=tmp_path,
            transport=transport,
            answer_format="structured",
            **FAST,
        )
    stages = by_stage(server)
    for req in stages["actions"]:
        fmt = req.body["response_format"]
        assert fmt["type"] == "json_schema" and fmt["json_schema"]["strict"] is True
        assert (
            fmt["json_schema"]["name"] == ACTIONS_SCHEMA.name
            and fmt["json_schema"]["schema"] == ACTIONS_SCHEMA.as_dict()
        )
        assert '{"actions": [[v1, c1]' in req.text  # the structured variant's wording
    assert all("response_format" not in r.body for r in stages["scene"] + stages["intent"])
    schema = ACTIONS_SCHEMA.as_dict()["properties"]["actions"]
    assert (schema["minItems"], schema["maxItems"], schema["items"]["minItems"], schema["items"]["maxItems"]) == (
        6,
        6,
        2,
        2,
    )
    assert schema["items"]["items"] == {"type": "number", "minimum": -MAGNITUDE, "maximum": MAGNITUDE}
    for rec in records(result).values():
        assert (rec["status"], rec["first_status"], rec["answer"]) == ("ok", "ok", GOOD_ACTIONS_JSON)
        assert np.allclose(rec["actions"], json.loads(GOOD_ACTIONS_JSON)["actions"])
    manifest = result.manifest
    assert (manifest["config"]["answer_format"], manifest["params"]["answer_format"]) == ("structured", "structured")
    assert manifest["structured_output"]["parse_mode"] == "json"
    assert manifest["structured_output"]["schema"] == ACTIONS_SCHEMA.as_dict()
    assert (
        "--api-base" not in manifest["structured_output"]["mechanism"]
        and server.url in manifest["structured_output"]["mechanism"]
    )
    described = load_prompt_set().select("independent", "structured").describe()
    assert manifest["prompt_set"] == described and described["variant"] == "structured"
    # the run records how it parsed (json), and evaluate scores it under that definition
    assert manifest["params"]["parse"]["mode"] == "json"
    (row,) = evaluate_runs([result.run_dir], resampling=Resampling(n_resamples=0)).accuracy_rows()
    assert row["parse"].startswith("json") and row["scored"] == len(frames) and row["fe_pct"] == 0.0


def test_a_structured_answer_outside_the_plausibility_limits_still_fails_and_is_reasked(tmp_path, frames):
    implausible = json.dumps({"actions": [[60.0, 0.0]] * 6})  # inside the schema's bound, outside the limits
    script = [None]

    def reply(req):
        if req.stage == "actions" and script[0] is None:
            script[0] = "sent"
            return Reply(implausible)
        return default_reply(req)

    with FakeOpenAIServer(reply) as server:
        result = run(
            "openai/gpt-4o", api_base=server.url, frames=frames[:1], output=tmp_path, answer_format="structured", **FAST
        )
    (rec,) = records(result).values()
    first, second = rec["attempts"]
    assert (first["status"], second["status"], rec["status"]) == ("failed", "ok", "ok")
    assert "speed 60 at step 1 outside" in first["reason"]
    assert [r.stage for r in server.requests] == ["scene", "intent", "actions", "actions"]


def test_evaluate_re_scores_a_structured_run_under_json_with_tighter_limits(tmp_path, frames, capsys):
    """``evaluate --parse json --speed-range`` re-reads the stored JSON answers: a tighter speed limit makes them implausible."""
    with FakeOpenAIServer() as server:
        result = run(
            "openai/gpt-4o",
            api_base=server.url,
            frames=frames,
            output=tmp_path / "runs",
            answer_format="structured",
            **FAST,
        )
    top = max(v for v, _ in json.loads(GOOD_ACTIONS_JSON)["actions"])
    rows = {}
    for limit in (top + 1.0, top - 0.5):
        assert (
            cli_main(
                [
                    "evaluate",
                    str(result.run_dir),
                    "--parse",
                    "json",
                    "--speed-range",
                    "-1",
                    str(limit),
                    "--format",
                    "json",
                    "--resamples",
                    "0",
                ]
            )
            == 0
        )
        rows[limit] = json.loads(capsys.readouterr().out)
    loose, tight = (
        [t for t in rows[limit]["tables"] if t["name"] == "accuracy_lightemma"][0]["rows"][0]
        for limit in (top + 1.0, top - 0.5)
    )
    assert (loose["scored"], loose["implausible"], loose["fe_pct"]) == (len(frames), 0, 0.0)
    assert loose["parse"] == f"json v∈[-1, {top + 1.0:g}]"
    assert (tight["scored"], tight["implausible"], tight["fe_pct"], tight["ade_avg"]) == (0, len(frames), 100.0, None)
    assert cli_main(["evaluate", str(result.run_dir), "--parse", "paper", "--speed-range", "0", "9"]) == 2
    assert "apply to lenient, strict and json parsing" in capsys.readouterr().err


def test_a_text_answer_to_a_structured_request_is_a_format_failure_not_read_leniently(tmp_path, frames):
    with FakeOpenAIServer(lambda req: Reply(GOOD_ACTIONS) if req.stage == "actions" else default_reply(req)) as server:
        result = run(
            "openai/gpt-4o",
            api_base=server.url,
            frames=frames[:1],
            output=tmp_path,
            answer_format="structured",
            max_attempts=2,
            **FAST,
        )
    (rec,) = records(result).values()
    assert rec["status"] == "failed" and rec["n_attempts"] == 2 and len(server.requests) == 4
    assert "not a JSON object" in rec["attempts"][0]["reason"]


@pytest.mark.parametrize(
    ("model", "sent"),
    [
        ("anthropic/claude-sonnet-4-6", "output_format"),  # native structured outputs
        ("claude-4.0-sonnet", "tools"),  # litellm's forced json_tool_call; the answer comes back as tool_use
        ("gemini/gemini-2.5-flash", "generationConfig"),
    ],
)
def test_native_providers_get_the_schema_through_litellm(monkeypatch, tmp_path, frames, model, sent):
    provider = "anthropic" if "claude" in model else "gemini"
    monkeypatch.setenv(NATIVE[provider], KEY)
    with FakeOpenAIServer() as server:
        result = run(
            model, api_base=server.root_url, frames=frames[:2], output=tmp_path, answer_format="structured", **FAST
        )
    for req in by_stage(server)["actions"]:
        assert sent in req.body and req.schema is not None
        pairs = req.schema["properties"]["actions"]
        assert pairs["items"]["items"]["type"] == "number"
        if sent == "output_format":  # Anthropic's grammar has no array lengths: litellm moves them into the description
            assert "minItems" not in pairs and "minimum number of items: 6" in pairs["description"]
        elif sent == "tools":  # a tool's input schema keeps them, as guidance: tool inputs are not grammar-enforced
            assert pairs["minItems"] == pairs["maxItems"] == 6 and req.forced_tool
        else:  # Gemini 2.5: the whole JSON schema (response_json_schema), lengths included
            config = req.body["generationConfig"]
            assert config.get("response_mime_type", config.get("responseMimeType")) == "application/json"
            assert pairs["minItems"] == pairs["maxItems"] == 6
    for req in by_stage(server)["scene"]:
        assert req.schema is None
    for rec in records(result).values():
        assert (rec["status"], rec["answer"]) == ("ok", GOOD_ACTIONS_JSON)
    assert result.manifest["structured_output"]["pair_count_enforced"] is (provider == "gemini")


def test_a_model_that_cannot_follow_a_schema_is_refused_before_the_run_starts(monkeypatch, tmp_path, frames, capsys):
    monkeypatch.setenv("GEMINI_API_KEY", KEY)
    with FakeOpenAIServer() as server:
        with pytest.raises(
            UserError, match=r"--answer-format structured: litellm .* does not mark gemini/gemini-2.0-flash"
        ):
            run(
                "gemini-2.0-flash",
                api_base=server.root_url,
                frames=frames,
                output=tmp_path / "py",
                answer_format="structured",
                **FAST,
            )
        code = cli_main(
            [
                "run",
                "--model",
                "gemini-2.0-flash",
                "--api-base",
                server.root_url,
                "--dataroot",
                str(tmp_path),
                "--answer-format",
                "structured",
                "--output",
                str(tmp_path / "cli"),
                "--no-progress",
            ]
        )
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert err.startswith("lightemma run: error: --answer-format structured:") and "--answer-format text" in err
    assert not server.requests and not (tmp_path / "py").exists() and not (tmp_path / "cli").exists()


def test_which_paper_models_can_follow_the_schema(monkeypatch):
    """As docs/run.md says: litellm's list refuses Gemini-2.0-Flash and Claude-3.7-Sonnet, accepts the other API rows."""
    from lightemma.backends import create_backend
    from lightemma.models.catalog import PAPER_MODELS

    for variable in ("OPENAI_API_KEY", "ANTHROPIC_API_KEY", "GEMINI_API_KEY"):
        monkeypatch.setenv(variable, KEY)
    accepted, refused = [], []
    for info in PAPER_MODELS:
        if info.backend != "api":
            continue
        backend = create_backend(info.key)
        try:
            mechanism = backend.structured_output()["mechanism"]
            accepted.append((info.key, mechanism.split()[0]))
        except UserError:
            refused.append(info.key)
    assert refused == ["claude-3.7-sonnet", "gemini-2.0-flash"]
    assert accepted == [
        ("gpt-4o", "response_format"),
        ("gpt-5.0", "response_format"),
        ("gpt-5.2", "response_format"),
        ("claude-4.0-sonnet", "Anthropic"),
        ("claude-4.6-sonnet", "Anthropic"),
        ("gemini-2.5-flash", "Gemini"),
        ("gemini-3.0-flash", "Gemini"),
    ]


def test_a_baseline_answers_the_structured_schema_itself(tmp_path, frames):
    result = run("baseline:cv", frames=frames, output=tmp_path, answer_format="structured", progress=False)
    for frame, rec in zip(frames, [records(result)[f.frame_id] for f in frames]):
        assert rec["status"] == "ok" and json.loads(rec["answer"]) == {
            "actions": [[frame.history_actions[-1, 0], 0.0]] * 6
        }


# -- the cache-aware layout ----------------------------------------------------------------------------


def _leading_image(req):
    role, parts = req.messages()[0]
    assert role == "user" and parts[0]["kind"] == "image"
    return parts[0]["data"]


@pytest.mark.parametrize("model", ["openai/gpt-4o", "anthropic/claude-sonnet-4-6", "gemini/gemini-2.5-flash"])
@pytest.mark.parametrize("chain", ["independent", "conversation"])
def test_every_request_of_a_frame_starts_with_the_same_image_part(monkeypatch, tmp_path, frames, model, chain):
    if not model.startswith("openai/"):
        monkeypatch.setenv(NATIVE[model.split("/")[0]], KEY)
    with FakeOpenAIServer() as server:
        run(model, api_base=api_base(server, model), frames=frames, output=tmp_path, chain=chain, concurrency=1, **FAST)
    assert len(server.requests) == 3 * len(frames)
    for k in range(len(frames)):
        frame_requests = server.requests[3 * k : 3 * k + 3]
        assert [r.stage for r in frame_requests] == ["scene", "intent", "actions"]
        assert (
            len({_leading_image(r) for r in frame_requests}) == 1
        )  # byte-identical image, first part of the first turn
        images = [p for r in frame_requests for _, parts in r.messages() for p in parts if p["kind"] == "image"]
        assert len(images) == 3  # once per request: never repeated inside a conversation
    assert len({_leading_image(server.requests[3 * k]) for k in range(len(frames))}) == len(frames)


@pytest.mark.parametrize("chain", ["independent", "conversation"])
def test_anthropic_requests_carry_a_cache_breakpoint_after_the_image(monkeypatch, tmp_path, frames, chain):
    monkeypatch.setenv("ANTHROPIC_API_KEY", KEY)
    with FakeOpenAIServer() as server:
        run(
            "anthropic/claude-sonnet-4-6",
            api_base=server.root_url,
            frames=frames[:1],
            output=tmp_path,
            chain=chain,
            **FAST,
        )
    marks = []
    for req in server.requests:
        body_parts = [p for m in req.body["messages"] for p in m["content"]]
        assert body_parts[0]["type"] == "image" and body_parts[0]["cache_control"] == {"type": "ephemeral"}
        marks.append(
            [
                (i, j)
                for i, m in enumerate(req.body["messages"])
                for j, p in enumerate(m["content"])
                if "cache_control" in p
            ]
        )
    if chain == "independent":
        assert marks == [[(0, 0)]] * 3
    else:  # and the end of the previous user turn (read) and of a request the next stage extends (written)
        assert marks == [[(0, 0), (0, 1)], [(0, 0), (0, 1), (2, 0)], [(0, 0), (2, 0)]]


@pytest.mark.parametrize("model", ["openai/gpt-4o", "gemini/gemini-2.5-flash"])
def test_no_cache_breakpoints_where_caching_is_automatic(monkeypatch, tmp_path, frames, model):
    if not model.startswith("openai/"):
        monkeypatch.setenv("GEMINI_API_KEY", KEY)
    with FakeOpenAIServer() as server:
        run(model, api_base=api_base(server, model), frames=frames[:1], output=tmp_path, chain="conversation", **FAST)
    assert "cache_control" not in json.dumps([r.body for r in server.requests])


# -- the conversation chain ----------------------------------------------------------------------------


def test_the_conversation_chain_carries_the_earlier_turns_and_a_reask_resends_them(tmp_path, frames):
    index = FrameIndex(frames)
    answered = set()

    def reply(req):
        i = index(req)
        if req.stage == "actions" and i not in answered:
            answered.add(i)
            return Reply("I would rather not say.")
        texts = {"scene": f"SCENE-OF-{i}", "intent": f"INTENT-OF-{i}", "actions": GOOD_ACTIONS}
        return Reply(texts[req.stage])

    prompts = load_prompt_set().select("conversation", "text")
    with FakeOpenAIServer(reply) as server:
        result = run("openai/gpt-4o", api_base=server.url, frames=frames, output=tmp_path, chain="conversation", **FAST)
    for i, frame in enumerate(frames):
        sent = [r for r in server.requests if index(r) == i]
        assert [r.stage for r in sent] == ["scene", "intent", "actions", "actions"]
        turns = [[(role, [p["kind"] for p in parts]) for role, parts in r.messages()] for r in sent]
        assert turns[0] == [("user", ["image", "text"])]
        assert turns[1] == [("user", ["image", "text"]), ("assistant", ["text"]), ("user", ["text"])]
        assert turns[2] == turns[3] == turns[1] + [("assistant", ["text"]), ("user", ["text"])]
        texts = [[p["text"] for _, parts in r.messages() for p in parts if p["kind"] == "text"] for r in sent]
        assert texts[2][:4] == [prompts.render("scene"), f"SCENE-OF-{i}", texts[1][2], f"INTENT-OF-{i}"]
        assert f"SCENE-OF-{i}" not in texts[1][2] and "past 3 seconds" in texts[1][2]  # the scene is a turn, not pasted
        assert f"({5.0 + 0.5 * i}, 0.0)" in texts[1][2]  # the history is in the intent turn
        assert texts[3] == texts[2]  # the re-ask resends the conversation; the failed answer is not shown
        assert texts[2][4] == prompts.render("actions") and "INTENT-OF" not in texts[2][4]
        rec = records(result)[frame.frame_id]
        assert (rec["status"], rec["first_status"], rec["n_attempts"]) == ("ok", "failed", 2)
        assert (rec["scene_text"], rec["intent_text"]) == (f"SCENE-OF-{i}", f"INTENT-OF-{i}")
    assert (
        result.manifest["params"]["chain"] == "conversation"
        and result.manifest["prompt_set"]["variant"] == "conversation"
    )


def test_a_chain_reask_starts_the_conversation_over(tmp_path, frames):
    calls = {"n": 0}

    def reply(req):
        if req.stage == "actions":
            calls["n"] += 1
            return Reply("no" if calls["n"] == 1 else GOOD_ACTIONS)
        return default_reply(req)

    with FakeOpenAIServer(reply) as server:
        run(
            "openai/gpt-4o",
            api_base=server.url,
            frames=frames[:1],
            output=tmp_path,
            chain="conversation",
            reask="chain",
            **FAST,
        )
    assert [len(r.body["messages"]) for r in server.requests] == [1, 3, 5, 1, 3, 5]


def test_conversation_and_structured_together(tmp_path, frames):
    with FakeOpenAIServer() as server:
        result = run(
            "openai/gpt-4o",
            api_base=server.url,
            frames=frames,
            output=tmp_path,
            chain="conversation",
            answer_format="structured",
            **FAST,
        )
    for req in by_stage(server)["actions"]:
        assert len(req.body["messages"]) == 5 and req.body["response_format"]["type"] == "json_schema"
    assert all(r["status"] == "ok" for r in records(result).values())
    assert result.manifest["prompt_set"]["variant"] == "conversation+structured"


# -- honest accounting -----------------------------------------------------------------------------------


def _run_counted(tmp_path, frames, model, *, cache, chain="independent", transport="litellm", name="run"):
    with FakeOpenAIServer(prefix_cache=cache, count_tokens=True) as server:
        result = run(
            model,
            api_base=api_base(server, model),
            frames=frames,
            output=tmp_path / name,
            chain=chain,
            transport=transport,
            concurrency=1,
            **FAST,
        )
    return result, server


@TRANSPORTS
def test_openai_cached_tokens_are_recorded_per_call_summed_per_frame_and_billed_at_the_cached_price(
    tmp_path, camera_frames, transport
):
    cached, server = _run_counted(
        tmp_path, camera_frames, "openai/gpt-4o", cache=True, transport=transport, name="cache"
    )
    plain, _ = _run_counted(tmp_path, camera_frames, "openai/gpt-4o", cache=False, transport=transport, name="plain")
    price_in, price_cached, price_out = 2.5e-6, 1.25e-6, 1e-5  # litellm's gpt-4o prices
    for rec, same in zip(records(cached).values(), records(plain).values()):
        calls = rec["attempts"][0]["calls"]
        assert [c["cached_input_tokens"] for c in calls][0] == 0
        assert all(c["cached_input_tokens"] >= 1024 and c["cached_input_tokens"] % 128 == 0 for c in calls[1:])
        assert rec["cached_input_tokens"] == sum(c["cached_input_tokens"] for c in calls)
        assert rec["input_tokens"] == same["input_tokens"] and [
            c["cached_input_tokens"] for c in same["attempts"][0]["calls"]
        ] == [0, 0, 0]
        for call in calls:
            expected = (
                (call["input_tokens"] - call["cached_input_tokens"]) * price_in
                + call["cached_input_tokens"] * price_cached
                + call["output_tokens"] * price_out
            ) * 100
            assert call["cost_cents"] == pytest.approx(expected)
        assert rec["cost_cents"] < same["cost_cents"]
    # the server's own count agrees with what the records carry
    assert [r.cached_tokens for r in server.requests] == [
        c["cached_input_tokens"] for rec in records(cached).values() for c in rec["attempts"][0]["calls"]
    ]
    assert 40 < cached.summary["cached_input_percent"] < 80 and "% of input from the prompt cache" in cached.report()


def test_anthropic_cache_reads_and_writes_are_recorded_and_billed_as_anthropic_bills_them(
    monkeypatch, tmp_path, camera_frames
):
    monkeypatch.setenv("ANTHROPIC_API_KEY", KEY)
    for chain in ("independent", "conversation"):
        cached, _ = _run_counted(
            tmp_path, camera_frames, "anthropic/claude-sonnet-4-6", cache=True, chain=chain, name=f"c-{chain}"
        )
        plain, _ = _run_counted(
            tmp_path, camera_frames, "anthropic/claude-sonnet-4-6", cache=False, chain=chain, name=f"p-{chain}"
        )
        for rec, same in zip(records(cached).values(), records(plain).values()):
            scene, intent, actions = rec["attempts"][0]["calls"]
            assert (
                scene["cached_input_tokens"] == 0 and scene["cache_write_tokens"] > 1800
            )  # the image (1844 tokens) written
            assert (
                intent["cached_input_tokens"] >= scene["cache_write_tokens"] and actions["cached_input_tokens"] > 1800
            )
            assert actions["cache_write_tokens"] == 0
            for call in (
                scene,
                intent,
                actions,
            ):  # $3 input, $0.30 cache read, $3.75 cache write, $15 output per million
                fresh = call["input_tokens"] - call["cached_input_tokens"] - call["cache_write_tokens"]
                usd = (
                    fresh * 3e-6
                    + call["cached_input_tokens"] * 3e-7
                    + call["cache_write_tokens"] * 3.75e-6
                    + call["output_tokens"] * 1.5e-5
                )
                assert call["cost_cents"] == pytest.approx(usd * 100)
            assert rec["cache_write_tokens"] == sum(c["cache_write_tokens"] for c in (scene, intent, actions))
            assert rec["cost_cents"] < same["cost_cents"]


def test_registry_priced_models_bill_cache_tokens_at_the_registrys_cache_prices(monkeypatch, tmp_path, camera_frames):
    monkeypatch.setenv("ANTHROPIC_API_KEY", KEY)
    result, _ = _run_counted(tmp_path, camera_frames[:1], "claude-3.7-sonnet", cache=True)  # not in litellm's list
    for call in next(iter(records(result).values()))["attempts"][0]["calls"]:
        fresh = call["input_tokens"] - call["cached_input_tokens"] - call["cache_write_tokens"]
        usd = (
            fresh * 3e-6
            + call["cached_input_tokens"] * 0.3e-6
            + call["cache_write_tokens"] * 3.75e-6
            + call["output_tokens"] * 15e-6
        )
        assert call["cost_cents"] == pytest.approx(usd * 100)


def test_gemini_reports_cached_tokens_only_when_there_are_some(monkeypatch, tmp_path, camera_frames):
    monkeypatch.setenv("GEMINI_API_KEY", KEY)
    result, server = _run_counted(tmp_path, camera_frames[:1], "gemini/gemini-2.5-flash", cache=True)
    calls = next(iter(records(result).values()))["attempts"][0]["calls"]
    # the first reply has no cachedContentTokenCount (Gemini leaves zeros out): recorded as 0, not unknown
    assert [r.cached_tokens for r in server.requests][0] == 0 and calls[0]["cached_input_tokens"] == 0
    assert calls[1]["cached_input_tokens"] >= 1548
    for call in calls:  # $0.30 input, $0.03 cached, $2.50 output per million
        usd = (
            (call["input_tokens"] - call["cached_input_tokens"]) * 3e-7
            + call["cached_input_tokens"] * 3e-8
            + call["output_tokens"] * 2.5e-6
        )
        assert call["cost_cents"] == pytest.approx(usd * 100)


def test_a_server_that_reports_no_cache_count_leaves_it_unknown(tmp_path, frames):
    with FakeOpenAIServer() as server:  # fixed usage without prompt_tokens_details, like a vLLM server by default
        result = run("openai/gpt-4o", api_base=server.url, frames=frames[:1], output=tmp_path, **FAST)
    (rec,) = records(result).values()
    assert rec["cached_input_tokens"] is None and all(
        c["cached_input_tokens"] is None for c in rec["attempts"][0]["calls"]
    )
    assert result.summary["cached_input_percent"] is None


def test_evaluate_shows_cached_percent_and_tells_variants_of_one_model_apart(tmp_path, camera_frames, capsys):
    from lightemma.evaluation import evaluate_runs

    dirs = []
    for chain in ("independent", "conversation"):
        result, _ = _run_counted(tmp_path, camera_frames, "openai/gpt-4o", cache=True, chain=chain, name=chain)
        dirs.append(result.run_dir)
    evaluation = evaluate_runs(dirs)
    rows = {r["model"]: r for r in evaluation.efficiency_rows()}
    assert set(rows) == {"openai/gpt-4o", "openai/gpt-4o [conversation]"}  # the paper's chain is not named
    for label, row in rows.items():
        recs = read_run(dirs[1] if "conversation" in label else dirs[0]).records
        total_cached = sum(r["cached_input_tokens"] for r in recs.values())
        total_input = sum(r["input_tokens"] for r in recs.values())
        assert row["cached_pct"] == pytest.approx(100 * total_cached / total_input)
        assert (
            row["chain"] == ("conversation" if "conversation" in label else "independent")
            and row["answer_format"] == "text"
        )
    # a conversation resends its earlier turns (more input) but all of them are a cached prefix
    conversation, independent = rows["openai/gpt-4o [conversation]"], rows["openai/gpt-4o"]
    assert (
        conversation["input_tokens"] > independent["input_tokens"]
        and conversation["cached_pct"] > independent["cached_pct"]
    )
    assert cli_main(["evaluate", *map(str, dirs)]) == 0
    out = capsys.readouterr().out
    assert "Cached (%)" in out and "openai/gpt-4o [conversation]" in out


# -- settings: recorded, resumed, refused -----------------------------------------------------------------


def test_resume_keeps_the_variant_and_refuses_to_change_it(tmp_path, frames, capsys):
    with FakeOpenAIServer() as server:
        result = run(
            "openai/gpt-4o",
            api_base=server.url,
            frames=frames,
            output=tmp_path,
            chain="conversation",
            answer_format="structured",
            **FAST,
        )
        code = cli_main(["run", "--resume", str(result.run_dir), "--chain", "independent"])
        assert code == 2 and "drop --chain" in capsys.readouterr().err
        from lightemma.pipeline import resume

        resume(result.run_dir, api_base=server.url, frames=frames, retry_failed=True, progress=False)
    assert len(server.requests) == 3 * len(frames)  # nothing failed: nothing re-run
    manifest = json.loads((result.run_dir / "manifest.json").read_text())
    assert (manifest["config"]["chain"], manifest["config"]["answer_format"]) == ("conversation", "structured")


def test_resume_refuses_a_changed_variant_template(tmp_path, frames):
    from importlib.resources import files

    prompt_file = tmp_path / "mine.json"
    data = json.loads(files("lightemma.prompts").joinpath("lightemma-v1.json").read_text(encoding="utf-8"))
    prompt_file.write_text(json.dumps(data))
    with FakeOpenAIServer() as server:
        result = run(
            "openai/gpt-4o",
            api_base=server.url,
            frames=frames[:1],
            output=tmp_path / "out",
            chain="conversation",
            prompt_set=str(prompt_file),
            **FAST,
        )
    data["variants"]["conversation"]["actions"] += " Thank you."
    prompt_file.write_text(json.dumps(data))
    from lightemma.pipeline import resume

    with pytest.raises(UserError, match="has changed since this run started"):
        resume(result.run_dir, api_base=server.url, frames=frames[:1], progress=False)
    data["variants"]["structured"]["actions"] += " Thanks."  # a variant the run does not use: no matter
    data["variants"]["conversation"]["actions"] = data["variants"]["conversation"]["actions"].removesuffix(
        " Thank you."
    )
    prompt_file.write_text(json.dumps(data))
    resume(result.run_dir, api_base=server.url, frames=frames[:1], progress=False)


def test_a_prompt_set_without_the_variant_is_refused_before_any_work(tmp_path, frames):
    prompt_file = tmp_path / "plain.json"
    plain = load_prompt_set()
    prompt_file.write_text(json.dumps({"name": "plain", "stages": plain.paper_stages}))
    with pytest.raises(UserError, match="has no 'conversation' variant, which --chain conversation needs"):
        run(
            "openai/gpt-4o",
            api_base="http://127.0.0.1:9/v1",
            frames=frames,
            output=tmp_path / "out",
            prompt_set=str(prompt_file),
            chain="conversation",
            **FAST,
        )
    assert not (tmp_path / "out").exists()


def test_variants_keep_the_paper_sets_hash_and_are_validated():
    prompts = load_prompt_set()
    assert (
        prompts.hash == "sha256:39c08838269eb01fc98b35b256f913be2440c09a4fa3438eada00ff5fee5658a"
    )  # as before variants
    assert prompts.select().describe() == {"name": "lightemma-v1", "hash": prompts.hash}
    assert prompts.select("conversation", "structured").select().stages == prompts.paper_stages
    from lightemma.prompts import PromptSet

    base = {"name": "x", "stages": prompts.paper_stages}
    with pytest.raises(UserError, match="unknown variant 'chatty'"):
        PromptSet.from_dict({**base, "variants": {"chatty": {"scene": "hi"}}})
    with pytest.raises(UserError, match=r"conversation variant's 'intent' template lacks placeholder\(s\) \{history\}"):
        PromptSet.from_dict({**base, "variants": {"conversation": {"intent": "What now?"}}})
    with pytest.raises(UserError, match=r"structured variant's 'actions' template lacks placeholder\(s\) \{scene\}"):
        PromptSet.from_dict({**base, "variants": {"structured": {"actions": "{history} {intent} JSON please"}}})
    ok = PromptSet.from_dict({**base, "variants": {"conversation": {"intent": "{history}", "actions": "Now act."}}})
    assert ok.hash == PromptSet.from_dict(base).hash


def test_the_response_cache_tells_variants_apart(tmp_path, frames):
    with FakeOpenAIServer() as server:
        for chain in ("independent", "conversation", "independent"):
            run(
                "openai/gpt-4o",
                api_base=server.url,
                frames=frames[:1],
                output=tmp_path,
                cache=True,
                chain=chain,
                **FAST,
            )
        assert len(server.requests) == 5  # the scene request is the same in both chains; the third run is all hits
        run(
            "openai/gpt-4o",
            api_base=server.url,
            frames=frames[:1],
            output=tmp_path,
            cache=True,
            answer_format="structured",
            **FAST,
        )
        assert len(server.requests) == 6  # only stage 3 differs (schema and wording)
