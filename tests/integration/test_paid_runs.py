"""Know the bill first (--estimate, the line before every paid run, --max-cost), --sample across scenes, --name."""

from __future__ import annotations

import json

import pytest

from lightemma.errors import RunStopped, UserError
from lightemma.frames.sample import sample_indices
from lightemma.models.catalog import PAPER_MODELS, lookup
from lightemma.models.prices import batch_price, price
from lightemma.models.tokens import image_tokens
from lightemma.pipeline.runner import estimate_run, resume, run
from lightemma.runs.store import read_run
from tests.support.fake_openai import FakeOpenAIServer, TokenCounter
from tests.support.fake_openai import image_tokens as oracle_image_tokens


def _frames(synth_root, **kw):
    import lightemma

    return lightemma.load_frames(synth_root, "v1.0-mini", split="all", **kw)


@pytest.mark.parametrize("size", [(1600, 900), (64, 36), (4000, 3000), (300, 300), (900, 1600)])
@pytest.mark.parametrize("provider", ["openai", "gemini"])
def test_image_tokens_follow_each_providers_published_rule(size, provider):
    # the loopback server's counter (tests/support/fake_openai.py) scales Anthropic images by the long side only; the documented
    # ~1,600-token area limit is tested against the docs' own figures in tests/unit/backends/test_image_rules.py
    assert image_tokens(*size, provider) == oracle_image_tokens(*size, provider)


def test_image_tokens_of_a_nuscenes_camera_frame():
    # CAM_FRONT is 1600 × 900: OpenAI 2 × 4 tiles after scaling to 1365 × 768, Anthropic 1456 × 819 (the documented
    # largest unresized 16:9 size) / 750, Gemini 3 × 2 tiles
    sizes = (image_tokens(1600, 900, "openai"), image_tokens(1600, 900, "anthropic"), image_tokens(1600, 900, "gemini"))
    assert sizes == (1105, 1590, 1548)
    with pytest.raises(ValueError):
        image_tokens(0, 900, "openai")


def test_every_paper_api_model_has_a_batch_price_at_half_its_list_price_with_a_source():
    for info in PAPER_MODELS:
        if info.backend != "api":
            assert batch_price(info)["input_usd_per_mtok"] is None
            continue
        listed, batch = price(info), batch_price(info)
        assert batch["input_usd_per_mtok"] == pytest.approx(listed["input_usd_per_mtok"] / 2), info.key
        assert batch["output_usd_per_mtok"] == pytest.approx(listed["output_usd_per_mtok"] / 2), info.key
        assert batch["source"] and ("batch" in batch["source"]), info.key


def test_the_estimate_counts_images_text_and_output_and_prices_both_modes(synth_root):
    frames = _frames(synth_root)
    est = estimate_run("gpt-4o", frames=frames)
    n = len(frames)
    assert est.frames == n and est.calls == 3 * n
    assert est.image_tokens == 3 * n * image_tokens(64, 36, "openai") and est.image_sizes == {"64×36": n}
    assert est.output_tokens == 341 * n  # the paper's Table I: GPT-4o, 341 output tokens per frame
    text = est.input_tokens - est.image_tokens
    assert 100 * 3 * n < text < 2000 * 3 * n  # the three prompts and the pasted answers, per call
    assert est.cost_cents == pytest.approx((est.input_tokens * 2.5 + est.output_tokens * 10.0) / 1e6 * 100)
    assert est.batch_cost_cents == pytest.approx(est.cost_cents / 2)
    claude = estimate_run("claude-3.7-sonnet", frames=frames)
    assert claude.provider == "anthropic" and claude.image_tokens == 3 * n * image_tokens(64, 36, "anthropic")
    with pytest.raises(
        UserError, match="0 calls to a provider, no cost: qwen-2.5-vl-7b runs on this machine through the hf backend"
    ):
        estimate_run("qwen-2.5-vl-7b", frames=frames)  # a local model: no bill, no image tokens by anyone's rule
    assert "~$" in est.line() and "with --batch" in est.line()


def test_the_estimate_is_close_to_what_an_emulated_provider_counts(synth_root, tmp_path):
    """The text rule against the loopback server's own token counter (4 bytes per token, the same image rule)."""
    with FakeOpenAIServer(count_tokens=True) as server:
        result = run(
            "openai/gpt-4o",
            dataroot=synth_root,
            version="v1.0-mini",
            split="all",
            api_base=server.url,
            output=tmp_path,
            progress=False,
            sample=3,
        )
    est = estimate_run("openai/gpt-4o", frames=_frames(synth_root).select(list(read_run(result.run_dir).records)))
    counted = sum(r["input_tokens"] for r in read_run(result.run_dir).records.values())
    # the estimate pastes typical answers (45 % / 35 % of the frame's output: the default 400 for a model the paper
    # did not run); the emulated model's are shorter
    from lightemma.pipeline.estimate import INTENT_SHARE, SCENE_SHARE
    from tests.support.fake_openai import INTENT_TEXT, SCENE_TEXT

    assert est.output_tokens == 3 * 400
    scene, intent = round(400 * SCENE_SHARE), round(400 * INTENT_SHARE)
    fake_scene, fake_intent = TokenCounter.text(SCENE_TEXT), TokenCounter.text(INTENT_TEXT)
    expected = est.input_tokens - 3 * (2 * scene + intent) + 3 * (2 * fake_scene + fake_intent)
    assert abs(expected - counted) / counted < 0.02, (expected, counted)


def test_cli_estimate_prints_the_bill_and_calls_nothing(synth_root, capsys, monkeypatch):
    from lightemma.cli import main

    monkeypatch.delenv("OPENAI_API_KEY", raising=False)  # no key needed: nothing is called
    code = main(
        [
            "run",
            "--model",
            "gpt-4o",
            "--dataroot",
            str(synth_root),
            "--version",
            "v1.0-mini",
            "--split",
            "all",
            "--sample",
            "5",
            "--estimate",
        ]
    )
    out = capsys.readouterr().out
    assert code == 0 and out.startswith("estimate: 5 frames, 15 calls") and "with --batch" in out
    assert "platform.openai.com/docs/guides/images-vision" in out and "the paper's Table I" in out


def test_the_estimate_uses_the_prompts_and_images_of_the_chosen_inputs(synth_root, tmp_path):
    from lightemma.pipeline.estimate import MESSAGE_TOKENS, text_tokens
    from lightemma.prompts import load_prompt_set

    frames = _frames(synth_root)
    n = len(frames)
    full = estimate_run("gpt-4o", frames=frames)
    no_image, blank = (
        estimate_run("gpt-4o", frames=frames, inputs="no-image"),
        estimate_run("gpt-4o", frames=frames, inputs="blank-image"),
    )
    no_history = estimate_run("gpt-4o", frames=frames, inputs="no-history")
    assert full.image_tokens == 3 * n * image_tokens(64, 36, "openai") > 0
    assert no_image.image_tokens == 0 and no_image.image_sizes == {} and no_image.missing_images == 0
    assert no_image.input_tokens == full.input_tokens - full.image_tokens and no_image.cost_cents < full.cost_cents
    assert "(0 image: --inputs no-image) + ~" in no_image.line() and "none (--inputs no-image" in no_image.report()
    assert blank.to_dict() | {"inputs": "full"} == full.to_dict()  # a blank image of the frame's size: the same tokens
    # no-history: the image as full, the no-history templates' text (stage 1 has no history either way)
    variant = load_prompt_set("lightemma-v1").select("independent", "text", "no-history")
    assert no_history.image_tokens == full.image_tokens
    assert no_history.input_tokens - no_history.image_tokens < full.input_tokens - full.image_tokens
    assert no_history.input_tokens - no_history.image_tokens >= n * 3 * MESSAGE_TOKENS + n * sum(
        text_tokens(variant.stages[stage].replace("{scene}", "").replace("{intent}", "")) - 2
        for stage in ("scene", "intent", "actions")
    )
    # the line a paid run prints first follows --inputs too
    lines = []
    with FakeOpenAIServer() as server:
        run(
            "openai/gpt-4o",
            dataroot=synth_root,
            version="v1.0-mini",
            split="all",
            api_base=server.url,
            output=tmp_path,
            progress=False,
            sample=2,
            inputs="no-image",
            log=lines.append,
        )
    assert any(
        line.startswith("estimate: 2 frames, 6 calls") and "(0 image: --inputs no-image)" in line for line in lines
    )


def test_cli_estimate_follows_inputs_and_has_no_bill_where_nothing_is_paid(synth_root, capsys, monkeypatch):
    from lightemma.cli import main

    monkeypatch.delenv("OPENAI_API_KEY", raising=False)
    base = ["run", "--dataroot", str(synth_root), "--version", "v1.0-mini", "--split", "all", "--estimate"]
    assert main([*base, "--model", "gpt-4o"]) == 0
    full = capsys.readouterr().out.splitlines()[0]
    assert main([*base, "--model", "gpt-4o", "--inputs", "no-image"]) == 0
    no_image = capsys.readouterr().out.splitlines()[0]
    assert "(0 image: --inputs no-image)" in no_image and "(0 image" not in full and no_image != full
    assert main([*base, "--model", "gpt-4o", "--inputs", "no-history"]) == 0
    assert capsys.readouterr().out.splitlines()[0] != full
    for model, extra, where in (
        ("baseline:cv", [], "runs here as a baseline"),
        ("qwen-2.5-vl-7b", ["--backend", "hf"], "runs on this machine through the hf backend (local compute)"),
    ):
        assert main([*base, "--model", model, *extra]) == 0
        out = capsys.readouterr().out
        assert out.count("\n") == 1 and "0 calls to a provider, no cost" in out and where in out, out
        assert "tokens" not in out and "rule" not in out
    assert main([*base, "--model", "baseline:cv", "--inputs", "no-image"]) == 2  # as a run refuses it
    assert "drop --inputs" in capsys.readouterr().err
    assert main([*base, "--model", "nonexistent-model-xyz"]) == 2
    captured = capsys.readouterr()
    assert captured.out == "" and "unknown model 'nonexistent-model-xyz'" in captured.err
    assert len(captured.err.strip().splitlines()) == 1


def test_a_sample_larger_than_the_set_is_refused(synth_root, tmp_path, capsys):
    from lightemma.cli import main

    n = len(_frames(synth_root))
    with pytest.raises(
        UserError, match=f"--sample 1000 is more than the {n} frames of the set; drop --sample to take them all"
    ):
        run(
            "baseline:cv",
            dataroot=synth_root,
            version="v1.0-mini",
            split="all",
            output=tmp_path,
            progress=False,
            sample=1000,
        )
    assert not list(tmp_path.glob("*/*/manifest.json"))  # nothing written
    base = ["run", "--model", "baseline:cv", "--dataroot", str(synth_root), "--version", "v1.0-mini", "--split", "all"]
    assert main([*base, "--sample", "1000", "--output", str(tmp_path)]) == 2
    assert f"--sample 1000 is more than the {n} frames" in capsys.readouterr().err
    assert main(["run", "--model", "gpt-4o", *base[3:], "--sample", "1000", "--estimate"]) == 2
    assert f"--sample 1000 is more than the {n} frames" in capsys.readouterr().err
    result = run(
        "baseline:cv", dataroot=synth_root, version="v1.0-mini", split="all", output=tmp_path, progress=False, sample=n
    )
    assert result.manifest["dataset"]["sample"]["n"] == n == result.manifest["dataset"]["sample"]["frames"]


def test_every_paid_run_prints_its_estimate_first_and_records_it(synth_root, tmp_path):
    lines = []
    with FakeOpenAIServer() as server:
        result = run(
            "openai/gpt-4o",
            dataroot=synth_root,
            version="v1.0-mini",
            split="all",
            api_base=server.url,
            output=tmp_path,
            progress=False,
            sample=2,
            log=lines.append,
        )
    assert any(line.startswith("estimate: 2 frames, 6 calls") for line in lines)
    assert lines.index(next(line for line in lines if line.startswith("estimate:"))) < lines.index(
        next(line for line in lines if line.startswith("run directory"))
    )
    manifest = json.loads((result.run_dir / "manifest.json").read_text())
    assert manifest["estimate"]["calls"] == 6


def test_max_cost_stops_cleanly_before_spending_more_and_a_resume_finishes(synth_root, tmp_path):
    # each call costs (1000 × 2.5 + 50 × 10) / 1e6 $ = 0.3 ¢; a frame 0.9 ¢; the estimate errs high per call
    with FakeOpenAIServer() as server:
        with pytest.raises(RunStopped) as stopped:
            run(
                "openai/gpt-4o",
                dataroot=synth_root,
                version="v1.0-mini",
                split="all",
                api_base=server.url,
                output=tmp_path,
                progress=False,
                concurrency=1,
                max_cost_cents=2.0,
            )
        assert stopped.value.cause == "budget" and "--max-cost 2" in str(stopped.value)
        run_dir = stopped.value.run_dir
        records = read_run(run_dir).records
        spent = sum(r["cost_cents"] for r in records.values())
        assert 0 < len(records) < 12 and spent <= 2.0
        assert len(server.requests) == 3 * len(records)  # no call beyond the frames that finished
        done = resume(run_dir, progress=False, max_cost_cents=100.0, api_base=server.url)
    assert len(read_run(run_dir).records) == 12 and done.summary["frames"] == 12


def test_max_cost_needs_a_known_price(synth_root, tmp_path):
    with FakeOpenAIServer() as server:
        with pytest.raises(UserError, match="--max-cost: the price of openai/no-such-price-model is unknown"):
            run(
                "openai/no-such-price-model",
                dataroot=synth_root,
                version="v1.0-mini",
                split="all",
                api_base=server.url,
                output=tmp_path,
                progress=False,
                max_cost_cents=5.0,
            )
        with pytest.raises(UserError, match="greater than 0"):
            run(
                "openai/gpt-4o",
                dataroot=synth_root,
                version="v1.0-mini",
                split="all",
                api_base=server.url,
                output=tmp_path,
                progress=False,
                max_cost_cents=0.0,
            )


def test_the_estimate_and_max_cost_price_calls_as_the_run_bills_them(synth_root, tmp_path, elsewhere):
    """--price is the price of every call (the estimate ignored it: $0.46 for $0.15); a model served from another
    --api-base has no list price, so its estimate is unknown and --max-cost needs --price (it bounded nothing:
    frames were admitted at gpt-4o's list price while the records, rightly unpriced, added nothing spent)."""
    frames = _frames(synth_root)
    given = estimate_run("gpt-4o", frames=frames, price=(1.0, 2.0))
    assert given.cost_cents == pytest.approx((given.input_tokens * 1.0 + given.output_tokens * 2.0) / 1e6 * 100)
    assert given.batch_cost_cents == given.cost_cents and given.price_source.startswith("--price 1 2")
    served = estimate_run("openai/gpt-4o", frames=frames, api_base="http://127.0.0.1:9/v1")
    assert served.cost_cents is None and served.batch_cost_cents is None
    assert served.price_source == "none: served from http://127.0.0.1:9/v1"
    assert "unknown normal, unknown with --batch" in served.line() and "~unknown" not in served.line()
    with pytest.raises(UserError, match="--price needs two numbers"):
        estimate_run("gpt-4o", frames=frames, price=(1.0, float("inf")))
    with FakeOpenAIServer() as server:
        with pytest.raises(UserError, match="none: served from .* give it with --price IN OUT"):
            run(
                "openai/gpt-4o",
                dataroot=synth_root,
                version="v1.0-mini",
                split="all",
                api_base=server.url,
                output=tmp_path / "a",
                progress=False,
                max_cost_cents=1.0,
            )
        assert not server.requests
        # each call: (1000 × 10 + 50 × 20) / 1e6 $ = 1.1 ¢, a frame 3.3 ¢: 5 ¢ admits one frame, not two
        with pytest.raises(RunStopped) as stopped:
            run(
                "openai/gpt-4o",
                dataroot=synth_root,
                version="v1.0-mini",
                split="all",
                api_base=server.url,
                output=tmp_path / "b",
                progress=False,
                concurrency=1,
                max_cost_cents=5.0,
                price=(10.0, 20.0),
            )
    records = read_run(stopped.value.run_dir).records
    assert stopped.value.cause == "budget" and len(records) == 1
    assert sum(r["cost_cents"] for r in records.values()) == pytest.approx(3 * 1.1)


def test_a_sample_spreads_over_scenes_is_reproducible_and_is_recorded(synth_root, tmp_path):
    frames = _frames(synth_root)
    assert len(set(frames.scene_names)) == 2
    first = frames.head(4)
    assert len(set(first.scene_names)) == 1  # what --limit does on this set: one scene
    picked = sample_indices(frames.scene_names, 4, seed=1)
    assert len({frames.scene_names[i] for i in picked}) == 2 and picked == sample_indices(frames.scene_names, 4, seed=1)
    assert picked != sample_indices(frames.scene_names, 4, seed=2) or picked != sample_indices(
        frames.scene_names, 4, seed=3
    )
    assert sample_indices(frames.scene_names, 100) == list(range(len(frames)))
    names = [f"s{i % 7}" for i in range(70)]
    assert len({names[i] for i in sample_indices(names, 5, seed=0)}) == 5  # N < scenes: N distinct scenes
    counts = [sum(1 for i in sample_indices(names, 21, seed=4) if names[i] == s) for s in sorted(set(names))]
    assert counts == [3] * 7  # N = 3 × scenes: three from each
    result = run(
        "baseline:cv",
        dataroot=synth_root,
        version="v1.0-mini",
        split="all",
        output=tmp_path,
        progress=False,
        sample=4,
        sample_seed=1,
    )
    manifest = json.loads((result.run_dir / "manifest.json").read_text())
    assert manifest["dataset"]["sample"] == {
        "n": 4,
        "seed": 1,
        "frames": 4,
        "scenes": 2,
        "rule": manifest["dataset"]["sample"]["rule"],
    }
    assert sorted(read_run(result.run_dir).records) == sorted(frames.frame_ids[i] for i in picked)
    again = resume(result.run_dir, progress=False)  # the resume loads the same sample
    assert again.frames_run == 0


def test_cli_sample_options_are_checked(synth_root, capsys):
    from lightemma.cli import main

    base = ["run", "--model", "baseline:cv", "--dataroot", str(synth_root), "--version", "v1.0-mini", "--split", "all"]
    assert main([*base, "--sample", "3", "--limit", "3"]) == 2
    assert "exclusive" in capsys.readouterr().err
    assert main([*base, "--sample-seed", "3"]) == 2
    assert "--sample-seed goes with --sample" in capsys.readouterr().err
    assert main([*base, "--sample", "0"]) == 2
    assert "--sample must be at least 1" in capsys.readouterr().err


def test_a_run_name_is_recorded_and_checked(synth_root, tmp_path):
    result = run(
        "baseline:cv",
        dataroot=synth_root,
        version="v1.0-mini",
        split="all",
        output=tmp_path,
        progress=False,
        sample=2,
        name="  ego baseline ",
    )
    assert json.loads((result.run_dir / "manifest.json").read_text())["name"] == "ego baseline"
    for bad in ("a\nb", "caf\udce9"):  # a line break; a byte that is not UTF-8 (a Latin-1 terminal's argv)
        with pytest.raises(UserError, match="^name must be 1 to 80 printable characters"):
            run(
                "baseline:cv",
                dataroot=synth_root,
                version="v1.0-mini",
                split="all",
                output=tmp_path,
                progress=False,
                name=bad,
            )
    assert lookup("gpt-4o") is not None


def test_lightemma_models_shows_batch_prices(capsys):
    from lightemma.cli import main

    assert main(["models", "--format", "json"]) == 0
    rows = {r["key"]: r for r in json.loads(capsys.readouterr().out)}
    assert rows["gpt-4o"]["batch_input_usd_per_mtok"] == pytest.approx(1.25)
    assert rows["claude-3.7-sonnet"]["batch_output_usd_per_mtok"] == pytest.approx(7.5)
    assert "batch-processing" in rows["claude-3.7-sonnet"]["batch_price_source"]
    assert rows["qwen-2.5-vl-7b"]["batch_price_source"] is None
    assert main(["models"]) == 0
    assert "| --batch $ in / out |" in capsys.readouterr().out


def test_price_covers_cached_tokens_and_a_call_of_unknown_cost_is_never_free_to_max_cost(synth_root, tmp_path):
    """--price left cached tokens unpriced: every call cost unknown, and --max-cost counted unknown as 0 (8 frames ran
    under a 4 ¢ limit). Cached and cache-write tokens are input tokens at --price's input price; a call whose cost is
    still unknown counts at the estimate."""
    import dataclasses

    from tests.support.fake_openai import default_reply

    cached = lambda req: dataclasses.replace(default_reply(req), cached_tokens=500)  # noqa: E731
    with FakeOpenAIServer(cached) as server:
        result = run(
            "openai/gpt-4o",
            dataroot=synth_root,
            version="v1.0-mini",
            split="all",
            api_base=server.url,
            output=tmp_path / "a",
            progress=False,
            sample=2,
            price=(10.0, 20.0),
        )
        calls = [c for r in read_run(result.run_dir).records.values() for a in r["attempts"] for c in a["calls"]]
        assert calls and all(c["cached_input_tokens"] == 500 for c in calls)
        assert all(c["cost_cents"] == pytest.approx((1000 * 10 + 50 * 20) / 1e6 * 100) for c in calls)
        manifest = json.loads((result.run_dir / "manifest.json").read_text())
        assert manifest["estimate"]["price_source"].startswith("--price 10 20")  # the line printed before the run too
    from lightemma.pipeline.estimate import Budget

    budget = Budget(4.0, per_call_cents=1.1)
    assert budget.reserve("f", first_call=True) == 1.1
    budget.settle(1.1, 0.0)
    assert budget.message().count("-0.00") == 0


def test_unknown_costs_count_at_the_estimate_under_max_cost(synth_root, tmp_path):
    """A provider that reports no usage: each call's cost is unknown, and --max-cost still stops the run."""
    import dataclasses

    from tests.support.fake_openai import default_reply

    unreported = lambda req: dataclasses.replace(default_reply(req), usage=False)  # noqa: E731
    with FakeOpenAIServer(unreported) as server:
        with pytest.raises(RunStopped) as stopped:
            run(
                "openai/gpt-4o",
                dataroot=synth_root,
                version="v1.0-mini",
                split="all",
                api_base=server.url,
                output=tmp_path,
                progress=False,
                concurrency=1,
                max_cost_cents=5.0,
                price=(10.0, 20.0),
            )
    records = read_run(stopped.value.run_dir).records
    assert stopped.value.cause == "budget" and 0 < len(records) < 12
    assert all(r["cost_cents"] is None for r in records.values())


def test_price_for_a_model_no_provider_bills_is_refused_and_a_resume_names_the_way_on(synth_root, tmp_path, elsewhere):
    with pytest.raises(
        UserError, match="--price is the price of a provider's tokens; baseline:cv runs on the baseline backend"
    ):
        run(
            "baseline:cv",
            dataroot=synth_root,
            version="v1.0-mini",
            split="all",
            output=tmp_path,
            progress=False,
            price=(1.0, 2.0),
        )
    from tests.support.fake_openai import Reply

    with FakeOpenAIServer(lambda req: Reply.error(401)) as server:  # stops at its first call: a run to resume
        with pytest.raises(RunStopped) as stopped:
            run(
                "openai/gpt-4o",
                dataroot=synth_root,
                version="v1.0-mini",
                split="all",
                api_base=server.url,
                output=tmp_path,
                progress=False,
                limit=2,
            )
        with pytest.raises(
            UserError, match="a resume keeps the run's price \\(it has none\\): drop --max-cost, or start a new run"
        ):
            resume(stopped.value.run_dir, progress=False, max_cost_cents=5.0, api_base=server.url)
