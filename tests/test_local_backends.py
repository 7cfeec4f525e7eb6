"""Local backends on tiny random-weight checkpoints, offline on CPU: hf end to end, batching, accounting; vllm.

The ``hf`` tests build real (tiny) Qwen2-VL, Qwen2.5-VL, Qwen3-VL and Mllama
checkpoints with :mod:`local_models` and load them exactly as real ones are
loaded. They need the ``hf`` extra (torch, torchvision, transformers) and are
never skipped. The ``vllm`` backend is tested here with an injected fake
``LLM``; the one end-to-end vLLM test runs only where vLLM is installed.
"""

import asyncio
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from local_models import FAMILIES, build_tiny_model
from PIL import Image

import lightemma.synth
from lightemma.backends.base import ChatRequest, GenerationParams
from lightemma.cli import main as cli_main
from lightemma.errors import UserError
from lightemma.runs.store import read_run

os.environ["HF_HUB_OFFLINE"] = "1"

MAX_TOKENS = 12
MAX_ATTEMPTS = 3
N_FRAMES = 4  # one synthetic scene of 18 keyframes gives 4 reference frames


@pytest.fixture(scope="module")
def dataroot(tmp_path_factory):
    root = tmp_path_factory.mktemp("synth")
    return lightemma.synth.write_dataset(root, scenes=1, keyframes=18, image_size=(64, 48), sweeps=False)


@pytest.fixture(scope="module", params=FAMILIES)
def tiny(request, tmp_path_factory):
    """(family, checkpoint path) for each tiny model family."""
    return request.param, build_tiny_model(request.param, tmp_path_factory.mktemp(request.param))


@pytest.fixture(scope="module")
def qwen2_vl(tmp_path_factory):
    return build_tiny_model("qwen2_vl", tmp_path_factory.mktemp("qwen2_vl_single"))


@pytest.fixture(scope="module")
def images(tmp_path_factory):
    """Six random JPEGs of varied sizes (so that batched rows have different prompt lengths)."""
    rng = np.random.default_rng(7)
    directory = tmp_path_factory.mktemp("images")
    paths = []
    for i, (w, h) in enumerate([(64, 48), (48, 64), (80, 48), (64, 64), (40, 40), (96, 56)]):
        path = directory / f"img{i}.jpg"
        Image.fromarray(rng.integers(0, 256, (h, w, 3), dtype=np.uint8)).save(path, quality=90)
        paths.append(str(path))
    return paths


def requests_for(images, stage="scene", max_tokens=MAX_TOKENS):
    texts = ["Describe the scene.", "What is ahead?", "Describe the vehicles, pedestrians and lane markings in detail.",
             "Lights?", "Predict speed and curvature for the next 6 steps.", "One paragraph of plain text, please."]
    return [ChatRequest(text=t, stage=stage, frame_id=f"f{i}", image_path=p, params=GenerationParams(max_tokens=max_tokens))
            for i, (t, p) in enumerate(zip(texts, images))]


def answer(backend, requests, *, together=False):
    """Results of ``requests``: one generate call each, concurrently (as the runner calls), or one call for all."""

    async def main():
        if together:
            out = await backend.generate(requests)
        else:
            out = [r for rs in await asyncio.gather(*(backend.generate([q]) for q in requests)) for r in rs]
        await backend.aclose()
        return out

    return asyncio.run(main())


def hf(path, **options):
    from lightemma.backends.hf import HFBackend

    options = {"dtype": "float32", "device": "cpu", **options}
    return HFBackend(str(path), **options)


# -- hf: the whole chain through `lightemma run` ------------------------------------------------------


def test_lightemma_run_with_the_hf_backend_runs_the_three_stage_chain_and_fills_in_accounting(tiny, dataroot, tmp_path, capsys):
    family, path = tiny
    code = cli_main(["run", "--backend", "hf", "--model", str(path), "--dataroot", str(dataroot), "--version", "v1.0-mini",
                     "--split", "all", "--limit", str(N_FRAMES), "--output", str(tmp_path), "--batch-size", "4",
                     "--max-tokens", str(MAX_TOKENS), "--max-attempts", str(MAX_ATTEMPTS), "--no-progress"])
    assert code == 0, capsys.readouterr().err
    (run_dir,) = [p.parent for p in tmp_path.glob("*/*/manifest.json")]
    contents = read_run(run_dir)
    manifest = contents.manifest
    assert contents.complete and len(contents.records) == N_FRAMES
    info = manifest["backend"]
    assert (info["backend"], info["model"], info["model_type"], info["gpus"], info["device"], info["dtype"]) == \
        ("hf", str(path), family, 0, "cpu", "float32")
    assert info["batch_size"] == 4 and "image" in info["token_counting"]
    assert manifest["config"]["backend_options"] == {"batch_size": 4}
    for record in contents.records.values():
        # random weights babble: every answer is a format error, re-asked (stage 3 only) up to the bound
        assert (record["status"], record["first_status"], record["n_attempts"]) == ("failed", "failed", MAX_ATTEMPTS)
        assert record["actions"] is None and record["trajectory"] is None
        stages = [[c["stage"] for c in a["calls"]] for a in record["attempts"]]
        assert stages == [["scene", "intent", "actions"]] + [["actions"]] * (MAX_ATTEMPTS - 1)
        calls = [c for a in record["attempts"] for c in a["calls"]]
        for attempt in record["attempts"]:
            assert attempt["reason"] and attempt["answer"] == attempt["calls"][-1]["text"]
        assert all(c["error"] is None and isinstance(c["text"], str) for c in calls)
        assert all(c["input_tokens"] > 0 and 1 <= c["output_tokens"] <= MAX_TOKENS for c in calls)
        assert all(c["cost_cents"] is None and c["seconds"] > 0 for c in calls)
        assert record["input_tokens"] == sum(c["input_tokens"] for c in calls)
        assert record["output_tokens"] == sum(c["output_tokens"] for c in calls)
        assert record["cost_cents"] is None
        # stage 2's prompt carries stage 1's answer, so it is longer than stage 1's
        assert calls[1]["input_tokens"] > calls[0]["input_tokens"]
        assert record["scene_text"] == calls[0]["text"]
    assert "failed 4" in capsys.readouterr().out


def test_a_run_batches_each_stage_across_the_frames_in_flight(qwen2_vl, dataroot, tmp_path):
    from lightemma.pipeline import run

    result = run(str(qwen2_vl), backend="hf", dataroot=dataroot, version="v1.0-mini", split="all", limit=N_FRAMES,
                 output=tmp_path, concurrency=N_FRAMES, max_tokens=MAX_TOKENS, max_attempts=2, progress=False,
                 backend_options={"batch_size": N_FRAMES, "batch_window": 2.0, "dtype": "float32"})
    records = list(read_run(result.run_dir).records.values())
    assert len(records) == N_FRAMES
    # each request's seconds is its batch's wall time: one batch per stage (and per re-ask) means one value
    for attempt, position in ((0, 0), (0, 1), (0, 2), (1, 0)):
        times = {r["attempts"][attempt]["calls"][position]["seconds"] for r in records}
        assert len(times) == 1, (attempt, position, times)
    scene_times = {r["attempts"][0]["calls"][0]["seconds"] for r in records}
    intent_times = {r["attempts"][0]["calls"][1]["seconds"] for r in records}
    assert scene_times != intent_times


# -- hf: batching is exact under greedy decoding ------------------------------------------------------


def test_batched_generation_equals_one_by_one_under_greedy_decoding(tiny, images):
    family, path = tiny
    requests = requests_for(images)
    single_backend = hf(path, batch_size=1)
    single = answer(single_backend, requests)
    batched_backend = hf(path, batch_size=4, batch_window=1.0)
    batched = answer(batched_backend, requests)
    together = answer(hf(path, batch_size=6), requests, together=True)
    assert single_backend.stats["max_batch_size"] == 1
    assert batched_backend.stats["max_batch_size"] == 4 and batched_backend.stats["batches"] == 2
    key = [(r.text, r.input_tokens, r.output_tokens, r.error) for r in single]
    assert [(r.text, r.input_tokens, r.output_tokens, r.error) for r in batched] == key
    assert [(r.text, r.input_tokens, r.output_tokens, r.error) for r in together] == key
    assert len({r.text for r in single}) > 1  # the rows really differ (different images and prompts)
    assert len({r.input_tokens for r in single}) > 1  # so the batch really was padded


# -- hf: token accounting -----------------------------------------------------------------------------


def test_input_tokens_count_the_image_tokens_each_model_has(tiny, images):
    family, path = tiny
    with_image = requests_for(images)[:2]
    without = [ChatRequest(text=r.text, stage=r.stage, frame_id=r.frame_id, params=r.params) for r in with_image]
    backend = hf(path, batch_size=4)
    got = answer(backend, [*with_image, *without])
    processor = backend._processor
    for i, path_ in enumerate(images[:2]):
        extra = got[i].input_tokens - got[i + 2].input_tokens
        if family == "mllama":
            assert extra == 1  # one <|image|> token; the image enters through cross-attention
        else:
            pixels = processor.image_processor(images=[Image.open(path_).convert("RGB")], return_tensors="pt")
            merged = int(pixels["image_grid_thw"][0].prod()) // processor.image_processor.merge_size ** 2
            assert extra == merged + 2  # <|vision_start|> + one <|image_pad|> per merged patch + <|vision_end|>


def test_output_tokens_stop_at_and_include_the_end_of_turn_token(qwen2_vl):
    backend = hf(qwen2_vl)
    eos = backend._processor.tokenizer.eos_token_id
    words = backend._processor.tokenizer.encode("left lane", add_special_tokens=False)
    pad = backend._processor.tokenizer.pad_token_id
    finished = backend._result([*words, eos, pad, pad], 10, 0.5)
    unfinished = backend._result(words, 10, 0.5)
    asyncio.run(backend.aclose())
    assert (finished.text, finished.output_tokens, finished.input_tokens, finished.cost_cents) == ("left lane", len(words) + 1, 10, None)
    assert (unfinished.text, unfinished.output_tokens) == ("left lane", len(words))


def test_max_pixels_caps_the_image_tokens_through_the_qwen_pixel_budget(qwen2_vl, tmp_path):
    big = tmp_path / "big.jpg"
    Image.fromarray(np.full((96, 128, 3), 120, dtype=np.uint8)).save(big)
    request = [ChatRequest(text="Describe.", stage="scene", frame_id="f", image_path=str(big), params=GenerationParams(max_tokens=2))]
    full_backend = hf(qwen2_vl)
    capped_backend = hf(qwen2_vl, max_pixels=32 * 32)
    full, capped = answer(full_backend, request)[0], answer(capped_backend, request)[0]
    assert full_backend.info["max_pixels"] is None and capped_backend.info["max_pixels"] == 1024
    assert capped_backend.info["image_cap"].startswith("processor pixel budget")

    def image_tokens(backend):
        processor = backend._processor.image_processor
        grid = processor(images=[Image.open(big).convert("RGB")], return_tensors="pt")["image_grid_thw"][0]
        return int(grid.prod()) // processor.merge_size ** 2

    # 16×16 px per merged token (8 px patches, 2×2 merge): at most 1024 / 256 = 4 tokens once capped
    assert image_tokens(capped_backend) <= 4 < image_tokens(full_backend)
    assert full.input_tokens - capped.input_tokens == image_tokens(full_backend) - image_tokens(capped_backend)


def test_cap_pixels_keeps_the_aspect_and_never_upscales():
    from lightemma.backends.local import cap_pixels

    assert cap_pixels(1600, 900, None) == (1600, 900)
    assert cap_pixels(64, 48, 10_000) == (64, 48)
    w, h = cap_pixels(1600, 900, 1600 * 900 // 4)
    assert (w, h) == (800, 450)
    w, h = cap_pixels(1601, 899, 100_000)
    assert w * h <= 100_000 and abs(w / h - 1601 / 899) < 0.01


# -- hf: errors and imports ---------------------------------------------------------------------------


def test_a_failed_batch_answers_each_request_with_an_error_not_text(qwen2_vl, images, tmp_path):
    missing = str(tmp_path / "missing.jpg")
    requests = [ChatRequest(text="Describe.", stage="scene", frame_id="f", image_path=missing, params=GenerationParams(max_tokens=2))]
    result = answer(hf(qwen2_vl), requests)[0]
    assert (result.ok, result.text, result.error) == (False, None, "UserError")
    assert "missing.jpg" in result.error_message


def test_a_directory_that_is_not_a_checkpoint_is_a_user_error(tmp_path):
    with pytest.raises(UserError, match="cannot load"):
        hf(tmp_path)


def test_bad_options_are_user_errors(qwen2_vl):
    with pytest.raises(UserError, match="--dtype"):
        hf(qwen2_vl.parent, dtype="int3")
    with pytest.raises(UserError, match="--batch-size"):
        hf(qwen2_vl, batch_size=0)
    with pytest.raises(UserError, match="--max-pixels"):
        hf(qwen2_vl, max_pixels=0)


def test_without_torch_the_hf_backend_says_which_extra_to_install(monkeypatch):
    from lightemma.backends import create_backend

    monkeypatch.setitem(sys.modules, "torch", None)
    with pytest.raises(UserError, match=r"pip install 'lightemma\[hf\]'"):
        create_backend("/some/checkpoint", backend="hf")


def test_importing_lightemma_and_the_local_backends_does_not_import_torch():
    code = ("import sys, lightemma, lightemma.backends, lightemma.backends.hf, "
            "lightemma.backends.batching, lightemma.cli.run\n"
            "heavy = sorted(m for m in ('torch', 'transformers', 'vllm') if m in sys.modules)\n"
            "print(heavy)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_local_options_are_refused_for_an_api_model(dataroot, tmp_path, capsys):
    code = cli_main(["run", "--model", "openai/gpt-4o", "--api-base", "http://127.0.0.1:9/v1", "--dataroot", str(dataroot),
                     "--batch-size", "8", "--output", str(tmp_path)])
    assert code == 2
    assert "--batch-size" in capsys.readouterr().err
    assert not list(tmp_path.iterdir())
