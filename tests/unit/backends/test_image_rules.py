"""Per-model image-token rules (issue 33 item 8), honest estimates where no rule is published, and what --max-cost
admits calls at; a refused --max-cost leaves nothing behind and a stopped run prints the resume command that works
(issue 32 items 9 and 14)."""

from __future__ import annotations

import re
import shlex

import pytest

from lightemma.errors import RunStopped, UserError
from lightemma.models.catalog import PAPER_MODELS, resolve
from lightemma.models.prices import reasoning_budget
from lightemma.pipeline.runner import estimate_run, run
from lightemma.runs.store import read_run
from tests.support.fake_openai import FakeOpenAIServer, Reply, default_reply

# the names this change adds are imported inside the tests, so that each test fails on its own without the change


def image_rule(model):
    from lightemma.models.tokens import image_rule as rule

    return rule(model)


def frame_cost_upper_bound(info, **kw):
    from lightemma.pipeline.estimate import frame_cost_upper_bound as bound

    return bound(info, **kw)


def _frames(synth_root):
    import lightemma

    return lightemma.load_frames(synth_root, "v1.0-mini", split="all")


# --- the rules against the documents' own worked examples --------------------------------------------------------


def test_openai_tile_rules_per_model():
    gpt4o, mini = image_rule("gpt-4o"), image_rule("gpt-4o-mini")
    # the docs' examples for gpt-4o: 1024 × 1024 → 4 tiles → 765; 2048 × 4096 → 1024 × 2048 → 768 × 1536 → 6 tiles
    # → 1105
    assert (gpt4o.tokens(1024, 1024), gpt4o.tokens(2048, 4096)) == (765, 1105)
    # gpt-4o-mini: 2833 + 5667 per tile; a 1600 × 900 frame is 2 × 3 tiles: 36,835 (billed), not gpt-4o's 1,105
    assert (mini.tokens(1024, 1024), mini.tokens(1600, 900)) == (2833 + 4 * 5667, 36_835)
    assert image_rule("openai/gpt-4o-mini-2024-07-18") is mini and image_rule("gpt-4o-2024-08-06") is gpt4o


def test_openai_patch_rules_per_model():
    # the docs' examples: 1024 × 1024 is 1024 patches; 1800 × 2400 is scaled to 1056 × 1408, 33 × 44 = 1452 patches;
    # tokens = patches × the model's multiplier, rounded up
    for model, multiplier in (("gpt-4.1-mini", 1.62), ("gpt-4.1-nano", 2.46), ("o4-mini", 1.72)):
        rule = image_rule(model)
        assert rule.kind == "patch" and rule.multiplier == multiplier
        assert rule.tokens(1024, 1024) == -(-1024 * multiplier // 1), model
        assert rule.tokens(1800, 2400) == -(-1452 * multiplier // 1), model
        assert rule.tokens(32, 32) == -(-multiplier // 1) and rule.tokens(2048, 768) == -(-1536 * multiplier // 1)


def test_anthropic_rule_resizes_to_the_documented_maximum():
    rule = image_rule("anthropic/claude-sonnet-4-6")
    # tokens = width × height / 750: the docs' examples 200 × 200 → ~54, 1000 × 1000 → ~1334, 1092 × 1092 → ~1590
    assert (rule.tokens(200, 200), rule.tokens(1000, 1000), rule.tokens(1092, 1092)) == (54, 1334, 1590)
    # the table's largest unresized sizes (1:1, 9:16) stay; larger images shrink to them: a 1600 × 900 camera frame is
    # 1456 × 819, ~1,590 tokens — not 1568 × 882 (1,844: long side only, above the ~1,600-token maximum)
    assert rule.tokens(819, 1456) == rule.tokens(1456, 819) == rule.tokens(1600, 900) == rule.tokens(4000, 4000) == 1590
    assert image_rule("anthropic/claude-3-7-sonnet-20250219") is rule
    assert image_rule("anthropic/claude-sonnet-4-20250514") is rule


def test_gemini_rules():
    two = image_rule("gemini/gemini-2.0-flash")
    assert image_rule("gemini/gemini-2.5-flash") is two
    # 258 within 384 × 384; else 258 per 768 × 768 tile (the docs' 600 × 400 example is one tile)
    assert (two.tokens(384, 384), two.tokens(600, 400), two.tokens(1600, 900)) == (258, 258, 1548)
    assert two.tokens(385, 10) == 258
    three = image_rule("gemini/gemini-3-flash-preview")
    # media resolution high, the default for images: at most 1120 tokens per image
    assert (three.tokens(1600, 900), three.tokens(64, 36), three.exact) == (1120, 1120, False)


def test_every_registry_api_model_has_a_cited_rule_or_none_by_a_stated_reason():
    from lightemma.models.tokens import IMAGE_RULES_READ

    with_rule, without = {}, set()
    for info in PAPER_MODELS:
        if info.backend != "api":
            assert image_rule(info) is None or info.backend == "api"
            continue
        rule = image_rule(info)
        if rule is None:
            without.add(info.key)
        else:
            with_rule[info.key] = rule
            assert re.search(r"(platform\.openai\.com|anthropic\.com|ai\.google\.dev)/", rule.source), info.key
            assert f"read {IMAGE_RULES_READ}" in rule.source, info.key
    # gpt-5 and gpt-5.2: no base/tile figures in any copy of OpenAI's page that could be read (registry.IMAGE_RULES)
    assert without == {"gpt-5.0", "gpt-5.2"}
    assert set(with_rule) == {
        "gpt-4o",
        "claude-3.7-sonnet",
        "claude-4.0-sonnet",
        "claude-4.6-sonnet",
        "gemini-2.0-flash",
        "gemini-2.5-flash",
        "gemini-3.0-flash",
    }
    # another provider's route or a model no rule names: unknown, not OpenAI's rule by default
    for name in ("openrouter/openai/gpt-4o", "openai/my-finetune", "gpt-4.1", "gpt-5-mini", "openai/Qwen/Qwen2-VL"):
        assert image_rule(name) is None, name
    with pytest.raises(ValueError, match="positive size"):
        image_rule("gpt-4o").tokens(0, 900)


# --- estimates ---------------------------------------------------------------------------------------------------


def test_the_estimate_counts_each_models_own_image_rule(synth_root):
    frames = _frames(synth_root)
    n = len(frames)
    mini, big = estimate_run("gpt-4o-mini", frames=frames), estimate_run("gpt-4o", frames=frames)
    assert mini.image_sizes == {"64×36": n}
    assert mini.image_tokens == 3 * n * (2833 + 5667) and big.image_tokens == 3 * n * (85 + 170)
    assert mini.input_tokens - mini.image_tokens == mini.text_tokens
    assert big.input_tokens - big.image_tokens == big.text_tokens
    assert "4o-mini row" in mini.report() and "2833 + 5667" in mini.report()
    gemini3 = estimate_run("gemini-3.0-flash", frames=frames)
    assert gemini3.image_tokens == 3 * n * 1120 and f"(at most {3 * n * 1120:,} image" in gemini3.line()


def test_an_unknown_image_rule_is_unknown_and_max_cost_admits_at_a_stated_upper_bound(synth_root):
    frames = _frames(synth_root)
    est = estimate_run("gpt-5.2", frames=frames)
    assert est.image_tokens is None and est.input_tokens is None
    assert est.cost_cents is None and est.batch_cost_cents is None and est.text_tokens > 0
    line = est.line()
    assert "unknown image tokens (no published image rule for gpt-5.2; 64×36)" in line
    assert "unknown normal, unknown with --batch" in line and "~$" not in line
    # the bound: the whole context window of input (litellm: 272,000) at the dearest input price, the output limit sent
    info = resolve("gpt-5.2")
    bound = frame_cost_upper_bound(info, max_tokens=512)
    output = 512 + reasoning_budget(info)
    assert (bound.input_tokens, bound.output_tokens) == (272_000, output) and bound.unknown is None
    assert bound.cents_per_call == pytest.approx((272_000 * 1.75 + output * 14.0) / 1e6 * 100)
    assert bound.cents_per_frame == pytest.approx(3 * bound.cents_per_call)
    assert est.admitted_cents_per_call() == pytest.approx(bound.cents_per_call)
    batch_bound = frame_cost_upper_bound(info, max_tokens=512, batch=True)
    assert est.admitted_cents_per_call(batch=True) == pytest.approx(batch_bound.cents_per_call)
    assert "each call admitted at its upper bound" in est.report() and "context window" in est.report()
    # no image shown: nothing unknown
    assert estimate_run("gpt-5.2", frames=frames, inputs="no-image").cost_cents is not None
    # a known rule: admitted at the estimate, as before
    known = estimate_run("gpt-4o", frames=frames)
    assert known.admitted_cents_per_call() == pytest.approx(known.cents_per_call) and known.bound is None


def test_cli_estimate_prints_unknown_for_the_image_part(synth_root, capsys, monkeypatch):
    from lightemma.cli import main

    monkeypatch.delenv("OPENAI_API_KEY", raising=False)
    assert (
        main(
            [
                "run",
                "--model",
                "gpt-5.2",
                "--dataroot",
                str(synth_root),
                "--version",
                "v1.0-mini",
                "--split",
                "all",
                "--estimate",
            ]
        )
        == 0
    )
    out = capsys.readouterr().out
    assert "unknown image tokens" in out and "image tokens: unknown: no published image rule for gpt-5.2" in out
    assert "--max-cost: each call admitted at its upper bound" in out


# --- --max-cost admits by the right rule -------------------------------------------------------------------------


def test_max_cost_holds_when_a_model_bills_images_at_its_own_rule(synth_root, tmp_path):
    """gpt-4o-mini bills a 64 × 36 image 8,500 tokens; counted at gpt-4o's 255, a limit of 2.5 frames let all 12 frames
    in at once (about 5 × the limit spent)."""
    frames = _frames(synth_root)
    est = estimate_run("gpt-4o-mini", frames=frames)
    # what the provider bills: the prompt's text and one 64 × 36 image at gpt-4o-mini's 2833 + 5667 per tile
    per_call_in = (est.input_tokens - est.image_tokens) // est.calls + 2833 + 5667
    per_call_out = est.output_tokens // est.calls

    def billed(req):  # a provider that bills every call as the estimate counts it (text + gpt-4o-mini's image rule)
        return Reply(default_reply(req).content, prompt_tokens=per_call_in, completion_tokens=per_call_out)

    frame_cents = 3 * (per_call_in * 0.15 + per_call_out * 0.6) / 1e6 * 100
    limit = 2.5 * frame_cents
    with FakeOpenAIServer(billed) as server:
        with pytest.raises(RunStopped) as stopped:
            run(
                "openai/gpt-4o-mini",
                dataroot=synth_root,
                version="v1.0-mini",
                split="all",
                api_base=server.url,
                output=tmp_path,
                progress=False,
                concurrency=12,
                max_cost_cents=limit,
            )
    records = read_run(stopped.value.run_dir).records
    spent = sum(r["cost_cents"] for r in records.values())
    assert stopped.value.cause == "budget" and len(records) == 2
    assert spent <= limit


def test_max_cost_without_an_image_rule_or_a_context_window_is_refused(synth_root, tmp_path, elsewhere):
    with FakeOpenAIServer() as server:
        # served from another --api-base: no context window is known, so nothing bounds a call
        with pytest.raises(
            UserError,
            match="image tokens of openai/gpt-5.2 are unknown .* context window is unknown .* drop --max-cost",
        ):
            run(
                "openai/gpt-5.2",
                dataroot=synth_root,
                version="v1.0-mini",
                split="all",
                api_base=server.url,
                output=tmp_path / "b",
                progress=False,
                max_cost_cents=1000.0,
                price=(1.75, 14.0),
            )
        assert not server.requests and not (tmp_path / "b").exists()


def test_max_cost_admits_a_model_without_an_image_rule_at_its_upper_bound(synth_root, tmp_path):
    frame_bound = frame_cost_upper_bound(resolve("gpt-5.2"), max_tokens=512).cents_per_frame
    with FakeOpenAIServer() as server:  # the loopback server plays OpenAI's own host: list price, known context window
        # below one frame's bound: refused before anything is called or written
        with pytest.raises(
            UserError,
            match=r"--max-cost 100: not one frame fits within it \(a frame is admitted at "
            f"{frame_bound:.3f} ¢",
        ):
            run(
                "openai/gpt-5.2",
                dataroot=synth_root,
                version="v1.0-mini",
                split="all",
                api_base=server.url,
                output=tmp_path / "a",
                progress=False,
                max_cost_cents=100.0,
            )
        assert not server.requests and not (tmp_path / "a").exists()
        # two frames' bounds fit: two frames in flight, all 12 done, each call's real cost settled as it ends
        result = run(
            "openai/gpt-5.2",
            dataroot=synth_root,
            version="v1.0-mini",
            split="all",
            api_base=server.url,
            output=tmp_path / "b",
            progress=False,
            concurrency=2,
            max_cost_cents=2.5 * frame_bound,
        )
        assert result.summary["frames"] == 12 and len(server.requests) == 36
        # a third frame in flight would not fit: the run stops there (resumable), as for any frame that does not fit
        with pytest.raises(RunStopped) as stopped:
            run(
                "openai/gpt-5.2",
                dataroot=synth_root,
                version="v1.0-mini",
                split="all",
                api_base=server.url,
                output=tmp_path / "c",
                progress=False,
                concurrency=12,
                max_cost_cents=2.5 * frame_bound,
            )
    assert stopped.value.cause == "budget" and f"the next frame (about {frame_bound:.3f} ¢)" in str(stopped.value)
    assert 2 <= len(read_run(stopped.value.run_dir).records) < 12  # two at once (more only if one ended first)


# --- issue 32 items 9 and 14 -------------------------------------------------------------------------------------


def test_a_refused_max_cost_leaves_no_run_directory(synth_root, tmp_path, elsewhere):
    with FakeOpenAIServer() as server:
        with pytest.raises(UserError, match="--max-cost: the price of openai/gpt-4o is unknown"):
            run(
                "openai/gpt-4o",
                dataroot=synth_root,
                version="v1.0-mini",
                split="all",
                api_base=server.url,
                output=tmp_path / "served",
                progress=False,
                max_cost_cents=5.0,
            )
        assert not server.requests
    with pytest.raises(UserError, match="--max-cost: the price of baseline:cv is unknown"):
        run(
            "baseline:cv",
            dataroot=synth_root,
            version="v1.0-mini",
            split="all",
            output=tmp_path / "baseline",
            progress=False,
            max_cost_cents=5.0,
        )
    assert not (tmp_path / "served").exists() and not (tmp_path / "baseline").exists()


def test_a_stopped_run_prints_the_resume_command_that_works(synth_root, tmp_path, monkeypatch, capsys):
    from lightemma.cli import main

    monkeypatch.setenv("MY_GATEWAY_KEY", "sk-test")
    state = {"fail": True}
    with FakeOpenAIServer(lambda req: Reply.error(401) if state["fail"] else default_reply(req)) as server:
        with pytest.raises(RunStopped) as stopped:
            run(
                "openai/gpt-4o",
                dataroot=synth_root,
                version="v1.0-mini",
                split="all",
                api_base=server.url,
                api_key_env="MY_GATEWAY_KEY",
                output=tmp_path,
                progress=False,
                limit=2,
                cache=True,
            )
        run_dir = stopped.value.run_dir
        command = re.search(r"continue with: (.*)$", str(stopped.value)).group(1)
        assert f"--resume {run_dir} --api-base {server.url} --api-key-env MY_GATEWAY_KEY --cache " in command
        from lightemma.pipeline.runner import resume_command

        assert command == resume_command(
            run_dir, {"api_base": server.url, "api_key_env": "MY_GATEWAY_KEY", "cache": "cache.sqlite"}
        )
        state["fail"] = False
        argv = shlex.split(command)
        assert argv[:2] == ["lightemma", "run"]
        assert main([*argv[1:], "--no-progress"]) == 0  # the printed command is accepted as it stands
    capsys.readouterr()
    assert len(read_run(run_dir).records) == 2
    assert resume_command(run_dir) == f"lightemma run --resume {shlex.quote(str(run_dir))}"
    assert "--trust-remote-code" in resume_command(run_dir, {"backend_options": {"trust_remote_code": True}})
