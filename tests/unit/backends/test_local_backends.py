"""Local backends on tiny random-weight checkpoints, offline on CPU: hf end to end, batching, accounting; vllm.

The ``hf`` tests build real (tiny) Qwen2-VL, Qwen2.5-VL, Qwen3-VL, Mllama and
Llama-4 checkpoints with :mod:`local_models` and load them exactly as real ones are
loaded. They need the ``hf`` extra (torch, torchvision, transformers) and are
never skipped. The ``vllm`` backend is tested here with an injected fake
``LLM``; the one end-to-end vLLM test runs only where vLLM is installed.
"""

import asyncio
import functools
import json
import os
import subprocess
import sys

import numpy as np
import pytest
from PIL import Image

import lightemma.frames
import lightemma.synth
from lightemma.backends.base import ChatRequest, GenerationParams
from lightemma.cli import main as cli_main
from lightemma.errors import UserError
from lightemma.runs.store import read_run
from tests.support.local_models import FAMILIES, build_tiny_model, teach_to_answer

os.environ["HF_HUB_OFFLINE"] = "1"

MAX_TOKENS = 12
MAX_ATTEMPTS = 3
N_FRAMES = 4  # one synthetic scene of 18 keyframes gives 4 reference frames


@pytest.fixture(scope="module", autouse=True)
def one_torch_thread():
    """Tiny models are overhead-bound: one intra-op thread is 3x faster than two and immune to busy neighbours."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


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


TAUGHT = "Keep the lane."


@pytest.fixture(scope="module")
def taught(tmp_path_factory, dataroot):
    """A tiny Qwen2-VL taught to answer every stage's prompt with "Keep the lane." and its end-of-turn token."""
    from lightemma.prompts import load_prompt_set

    prompts = load_prompt_set()
    frames = lightemma.load_frames(dataroot, "v1.0-mini", split="all")
    history = lightemma.frames.format_history(frames[0].history_actions)
    texts = [
        prompts.render("scene"),
        prompts.render("intent", scene=TAUGHT, history=history),
        prompts.render("actions", scene=TAUGHT, history=history, intent=TAUGHT),
    ]
    path = build_tiny_model("qwen2_vl", tmp_path_factory.mktemp("qwen2_vl_taught"))
    return teach_to_answer(path, TAUGHT, prompts=texts, image=frames[0].image_path)


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
    texts = [
        "Describe the scene.",
        "What is ahead?",
        "Describe the vehicles, pedestrians and lane markings in detail.",
        "Lights?",
        "Predict speed and curvature for the next 6 steps.",
        "One paragraph of plain text, please.",
    ]
    return [
        ChatRequest(text=t, stage=stage, frame_id=f"f{i}", image_path=p, params=GenerationParams(max_tokens=max_tokens))
        for i, (t, p) in enumerate(zip(texts, images))
    ]


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


@pytest.mark.slow
def test_lightemma_run_with_the_hf_backend_records_truncated_babble_truthfully(tiny, dataroot, tmp_path, capsys):
    """Random weights babble to the output limit: each scene text is cut off, recorded, and never passed on."""
    family, path = tiny
    code = cli_main(
        [
            "run",
            "--backend",
            "hf",
            "--model",
            str(path),
            "--dataroot",
            str(dataroot),
            "--version",
            "v1.0-mini",
            "--split",
            "all",
            "--limit",
            str(N_FRAMES),
            "--output",
            str(tmp_path),
            "--batch-size",
            "4",
            "--max-tokens",
            str(MAX_TOKENS),
            "--max-attempts",
            str(MAX_ATTEMPTS),
            "--no-progress",
        ]
    )
    out, err = capsys.readouterr()
    assert code == 1 and "no valid frame" in err, err  # a run without one valid frame exits non-zero
    (run_dir,) = [p.parent for p in tmp_path.glob("*/*/manifest.json")]
    contents = read_run(run_dir)
    manifest = contents.manifest
    assert contents.complete and len(contents.records) == N_FRAMES
    info = manifest["backend"]
    assert (info["backend"], info["model"], info["model_type"], info["gpus"], info["device"], info["dtype"]) == (
        "hf",
        str(path),
        family,
        0,
        "cpu",
        "float32",
    )
    assert info["batch_size"] == 4 and "image" in info["token_counting"]
    assert manifest["config"]["backend_options"] == {"batch_size": 4}
    for record in contents.records.values():
        # no stage-3 answer was ever received (every scene text was cut off): no first status, no format error
        assert (record["status"], record["first_status"], record["n_attempts"]) == ("failed", None, MAX_ATTEMPTS)
        assert record["failure"] == "truncated"
        assert record["actions"] is None and record["trajectory"] is None and record["scene_text"] is None
        # the cut-off scene text is asked again, never pasted into stage 2
        assert [[c["stage"] for c in a["calls"]] for a in record["attempts"]] == [["scene"]] * MAX_ATTEMPTS
        for attempt in record["attempts"]:
            assert attempt["failure"] == "truncated" and attempt["reason"].startswith("truncated")
            assert attempt["error"] is None and attempt["answer"] is None
        calls = [c for a in record["attempts"] for c in a["calls"]]
        assert all(c["finish_reason"] == "length" and c["output_tokens"] == MAX_TOKENS for c in calls)
        assert all(isinstance(c["text"], str) and c["error"] is None for c in calls)
        assert all(c["input_tokens"] > 0 and c["cost_cents"] is None and c["seconds"] > 0 for c in calls)
        assert record["input_tokens"] == sum(c["input_tokens"] for c in calls)
        assert record["output_tokens"] == MAX_TOKENS * MAX_ATTEMPTS and record["cost_cents"] is None
    assert "failed 4" in out and f"{N_FRAMES * MAX_ATTEMPTS} truncated" in out


@pytest.mark.slow
def test_the_hf_chain_passes_each_finished_text_on_and_fills_in_accounting(taught, dataroot, tmp_path, capsys):
    """A tiny model taught to end its answers goes through all three stages, then re-asks stage 3."""
    code = cli_main(
        [
            "run",
            "--backend",
            "hf",
            "--model",
            str(taught),
            "--dataroot",
            str(dataroot),
            "--version",
            "v1.0-mini",
            "--split",
            "all",
            "--limit",
            str(N_FRAMES),
            "--output",
            str(tmp_path),
            "--batch-size",
            "4",
            "--max-tokens",
            str(MAX_TOKENS),
            "--max-attempts",
            str(MAX_ATTEMPTS),
            "--no-progress",
        ]
    )
    out, err = capsys.readouterr()
    assert code == 1 and "no valid frame" in err, err  # "Keep the lane." is no list of actions
    (run_dir,) = [p.parent for p in tmp_path.glob("*/*/manifest.json")]
    for record in read_run(run_dir).records.values():
        assert (record["status"], record["first_status"], record["n_attempts"]) == ("failed", "failed", MAX_ATTEMPTS)
        stages = [[c["stage"] for c in a["calls"]] for a in record["attempts"]]
        assert stages == [["scene", "intent", "actions"]] + [["actions"]] * (MAX_ATTEMPTS - 1)
        calls = [c for a in record["attempts"] for c in a["calls"]]
        assert all(c["text"] == TAUGHT and c["finish_reason"] == "stop" for c in calls)
        for attempt in record["attempts"]:
            assert attempt["reason"] and attempt["answer"] == TAUGHT and attempt["failure"] == "format"
        assert all(1 <= c["output_tokens"] <= MAX_TOKENS for c in calls)
        assert record["input_tokens"] == sum(c["input_tokens"] for c in calls)
        assert record["output_tokens"] == sum(c["output_tokens"] for c in calls)
        # stage 2's prompt carries stage 1's answer, so it is longer than stage 1's
        assert calls[1]["input_tokens"] > calls[0]["input_tokens"]
        assert record["scene_text"] == record["intent_text"] == TAUGHT


@pytest.mark.slow
def test_a_run_batches_each_stage_across_the_frames_in_flight(taught, dataroot, tmp_path):
    from lightemma.pipeline import run

    result = run(
        str(taught),
        backend="hf",
        dataroot=dataroot,
        version="v1.0-mini",
        split="all",
        limit=N_FRAMES,
        output=tmp_path,
        concurrency=N_FRAMES,
        max_tokens=MAX_TOKENS,
        max_attempts=2,
        progress=False,
        backend_options={"batch_size": N_FRAMES, "batch_window": 2.0, "dtype": "float32"},
    )
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


@pytest.mark.slow
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


@pytest.mark.slow
def test_input_tokens_count_the_image_tokens_each_model_has(tiny, images):
    family, path = tiny
    with_image = requests_for(images)[:2]
    without = [ChatRequest(text=r.text, stage=r.stage, frame_id=r.frame_id, params=r.params) for r in with_image]
    backend = hf(path, batch_size=4)
    got = answer(backend, [*with_image, *without])
    processor = backend._processor
    for i, path_ in enumerate(images[:2]):
        extra = got[i].input_tokens - got[i + 2].input_tokens
        image = Image.open(path_).convert("RGB")
        if family == "mllama":
            assert extra == 1  # one <|image|> token; the image enters through cross-attention
        elif family == "llama4":
            # <|image_start|>, <|patch|> per (pixel-shuffled) patch of each tile and the global view, separators,
            # <|image|>, <|image_end|>: count them in what the processor makes of a bare image
            specials = {
                processor.tokenizer.convert_tokens_to_ids(t)
                for t in (
                    "<|image_start|>",
                    "<|image_end|>",
                    "<|image|>",
                    "<|patch|>",
                    "<|tile_x_separator|>",
                    "<|tile_y_separator|>",
                )
            }
            ids = processor(text=["<|image|>"], images=[[image]], return_tensors="pt")["input_ids"][0].tolist()
            assert extra == sum(t in specials for t in ids) > 4
        else:
            pixels = processor.image_processor(images=[image], return_tensors="pt")
            merged = int(pixels["image_grid_thw"][0].prod()) // processor.image_processor.merge_size**2
            assert extra == merged + 2  # <|vision_start|> + one <|image_pad|> per merged patch + <|vision_end|>


@pytest.mark.slow
def test_output_tokens_stop_at_and_include_the_end_of_turn_token(qwen2_vl):
    backend = hf(qwen2_vl)
    eos = backend._processor.tokenizer.eos_token_id
    words = backend._processor.tokenizer.encode("left lane", add_special_tokens=False)
    pad = backend._processor.tokenizer.pad_token_id
    finished = backend._result([*words, eos, pad, pad], 10, 0.5)
    unfinished = backend._result(words, 10, 0.5)
    asyncio.run(backend.aclose())
    assert (finished.text, finished.output_tokens, finished.input_tokens, finished.cost_cents) == (
        "left lane",
        len(words) + 1,
        10,
        None,
    )
    assert (unfinished.text, unfinished.output_tokens) == ("left lane", len(words))


@pytest.mark.slow
def test_max_pixels_caps_the_image_tokens_through_the_qwen_pixel_budget(qwen2_vl, tmp_path):
    big = tmp_path / "big.jpg"
    Image.fromarray(np.full((96, 128, 3), 120, dtype=np.uint8)).save(big)
    request = [
        ChatRequest(
            text="Describe.", stage="scene", frame_id="f", image_path=str(big), params=GenerationParams(max_tokens=2)
        )
    ]
    full_backend = hf(qwen2_vl)
    capped_backend = hf(qwen2_vl, max_pixels=32 * 32)
    full, capped = answer(full_backend, request)[0], answer(capped_backend, request)[0]
    assert full_backend.info["max_pixels"] is None and capped_backend.info["max_pixels"] == 1024
    assert capped_backend.info["image_cap"].startswith("processor pixel budget")

    def image_tokens(backend):
        processor = backend._processor.image_processor
        grid = processor(images=[Image.open(big).convert("RGB")], return_tensors="pt")["image_grid_thw"][0]
        return int(grid.prod()) // processor.merge_size**2

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


@pytest.mark.slow
def test_a_failed_batch_answers_each_request_with_an_error_not_text(qwen2_vl, images, tmp_path):
    missing = str(tmp_path / "missing.jpg")
    requests = [
        ChatRequest(
            text="Describe.", stage="scene", frame_id="f", image_path=missing, params=GenerationParams(max_tokens=2)
        )
    ]
    result = answer(hf(qwen2_vl), requests)[0]
    assert (result.ok, result.text, result.error) == (False, None, "UserError")
    assert "missing.jpg" in result.error_message


@pytest.mark.slow
def test_a_model_family_the_installed_transformers_cannot_generate_with_stops_the_run_in_one_line(
    qwen2_vl, dataroot, tmp_path, capsys, monkeypatch
):
    """A library regression (every forward raises the same error) is one run-fatal line, not a failure per frame."""
    import transformers
    from transformers import Qwen2VLForConditionalGeneration

    forwards = []
    original = Qwen2VLForConditionalGeneration.forward

    @functools.wraps(original)  # generate() reads forward's signature
    def broken(self, *args, **kwargs):
        forwards.append(1)
        raise AttributeError("'MoeCausalLMOutputWithPast' object has no attribute 'image_outputs'")

    monkeypatch.setattr(Qwen2VLForConditionalGeneration, "forward", broken)
    monkeypatch.delenv("LIGHTEMMA_DEBUG", raising=False)
    args = [
        "--dataroot",
        str(dataroot),
        "--version",
        "v1.0-mini",
        "--split",
        "all",
        "--limit",
        str(N_FRAMES),
        "--output",
        str(tmp_path),
        "--max-tokens",
        "4",
        "--max-attempts",
        "2",
        "--no-progress",
    ]
    code = cli_main(
        ["run", "--backend", "hf", "--model", str(qwen2_vl), "--batch-size", "2", "--dtype", "float32", *args]
    )
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if "error:" in line]
    assert code == 2 and len(lines) == 1 and "Traceback" not in err, err
    assert (
        f"transformers {transformers.__version__} cannot generate with qwen2_vl: AttributeError: "
        "'MoeCausalLMOutputWithPast' object has no attribute 'image_outputs'"
    ) in lines[0]
    assert "--resume" in lines[0]
    assert len(forwards) == 2  # two batches of two frames each, then nothing more
    (run_dir,) = [p.parent for p in tmp_path.glob("*/*/manifest.json")]
    stopped = read_run(run_dir)
    assert stopped.records == {} and not stopped.complete  # no frame marked failed for the library's fault
    assert stopped.manifest["sessions"][-1]["stopped"]["cause"] == "local-model"
    monkeypatch.setattr(Qwen2VLForConditionalGeneration, "forward", original)  # "after the fix"
    assert cli_main(["run", "--resume", str(run_dir), "--no-progress"]) == 1  # random weights: no valid frame, but done
    resumed = read_run(run_dir)
    assert len(resumed.records) == N_FRAMES and resumed.complete and resumed.duplicates == 0


def test_a_directory_that_is_not_a_checkpoint_is_a_user_error(tmp_path):
    with pytest.raises(UserError, match="cannot load"):
        hf(tmp_path)


@pytest.mark.slow
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


@pytest.mark.slow
def test_importing_lightemma_and_the_local_backends_does_not_import_torch():
    code = (
        "import sys, lightemma, lightemma.backends, lightemma.backends.hf, lightemma.backends.vllm, "
        "lightemma.backends.batching, lightemma.backends.ray, lightemma.cli.run, lightemma.pipeline.runner\n"
        "heavy = sorted(m for m in ('torch', 'transformers', 'vllm', 'ray') if m in sys.modules)\n"
        "print(heavy)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_local_options_are_refused_for_an_api_model(dataroot, tmp_path, capsys):
    code = cli_main(
        [
            "run",
            "--model",
            "openai/gpt-4o",
            "--api-base",
            "http://127.0.0.1:9/v1",
            "--dataroot",
            str(dataroot),
            "--batch-size",
            "8",
            "--output",
            str(tmp_path),
        ]
    )
    assert code == 2
    assert "--batch-size" in capsys.readouterr().err
    assert not list(tmp_path.iterdir())


# -- vllm: request building, batching and accounting against a stand-in engine ------------------------


class FakeSamplingParams:
    def __init__(self, *, temperature, max_tokens, structured_outputs=None):
        self.temperature, self.max_tokens, self.structured_outputs = temperature, max_tokens, structured_outputs


class FakeStructuredOutputsParams:
    """Stands in for ``vllm.sampling_params.StructuredOutputsParams`` (vLLM >= 0.12)."""

    def __init__(self, *, json=None, disable_any_whitespace=False):
        self.json, self.disable_any_whitespace = json, disable_any_whitespace


class FakeLLM:
    """Stands in for ``vllm.LLM``: records what it is given; answers stage 3 badly in its first stage-3 chat call
    (as JSON when its sampling parameters carry structured outputs).

    Its token counts follow vLLM's: ``prompt_token_ids`` includes 100 image tokens when an image is given
    and ``num_cached_tokens`` is that image prefix from the second request of the same image on.
    """

    instances = []

    def __init__(self, model, **kwargs):
        self.model, self.kwargs, self.calls, self.seen, self.action_calls = model, kwargs, [], set(), 0
        model_type = "qwen2_5_vl" if "mllama" not in str(model) else "mllama"
        self.llm_engine = type(
            "E", (), {"model_config": type("C", (), {"hf_config": type("H", (), {"model_type": model_type})})}
        )
        FakeLLM.instances.append(self)

    def chat(self, conversations, sampling_params=None, use_tqdm=True):
        self.calls.append((conversations, sampling_params, use_tqdm))
        self.action_calls += any("v1, c1" in c[-1]["content"][-1]["text"] for c in conversations)
        return [self._answer(c, sampling_params) for c in conversations]

    def _answer(self, conversation, sampling):
        first = conversation[0]["content"]
        image = first[0]["image_pil"] if first[0]["type"] == "image_pil" else None
        text = conversation[-1]["content"][-1]["text"]
        key = image.tobytes() if image is not None else b""
        cached = 100 if key in self.seen else 0
        self.seen.add(key)
        if "v1, c1" in text:
            good = "[(5.0, 0.0), (5.1, 0.0), (5.2, 0.0), (5.3, 0.0), (5.4, 0.0), (5.5, 0.0)]"
            if sampling.structured_outputs is not None:
                good = json.dumps({"actions": [[5.0 + 0.1 * k, 0.0] for k in range(6)]})
            answer = "I would rather not say." if self.action_calls == 1 else good
        else:
            answer = f"A road seen in {image.size[0]}x{image.size[1]} pixels." if image else "No image."
        words = answer.split()[: sampling.max_tokens]
        completion = type("Completion", (), {"text": " ".join(words), "token_ids": list(range(len(words) + 1))})
        n_words = sum(len(p["text"].split()) for turn in conversation for p in turn["content"] if p["type"] == "text")
        prompt = list(range(n_words + (100 if image is not None else 0)))
        return type(
            "RequestOutput", (), {"prompt_token_ids": prompt, "outputs": [completion], "num_cached_tokens": cached}
        )


@pytest.fixture
def fake_vllm(monkeypatch):
    """A stand-in ``vllm`` module (``LLM``, ``SamplingParams``), installed as ``sys.modules['vllm']``."""
    module = type(sys)("vllm")
    module.LLM, module.SamplingParams, module.__version__ = FakeLLM, FakeSamplingParams, "0.32.0-fake"
    module.sampling_params = type(sys)("vllm.sampling_params")
    module.sampling_params.StructuredOutputsParams = FakeStructuredOutputsParams
    FakeLLM.instances.clear()
    monkeypatch.setitem(sys.modules, "vllm", module)
    return module


def vllm_backend(**options):
    from lightemma.backends.vllm import VLLMBackend

    return VLLMBackend("Qwen/Qwen2.5-VL-7B-Instruct", **options)


def test_vllm_sends_one_chat_per_stage_batch_with_the_image_first_and_greedy_sampling(fake_vllm, images):
    backend = vllm_backend(batch_size=4, batch_window=1.0, tensor_parallel_size=2, max_pixels=40 * 30)
    (llm,) = FakeLLM.instances
    assert llm.model == "Qwen/Qwen2.5-VL-7B-Instruct"
    assert llm.kwargs["limit_mm_per_prompt"] == {"image": 1} and llm.kwargs["enable_prefix_caching"] is True
    assert (llm.kwargs["tensor_parallel_size"], llm.kwargs["gpu_memory_utilization"]) == (2, 0.9)
    requests = requests_for(images, max_tokens=7)
    results = answer(backend, requests)
    assert [len(c[0]) for c in llm.calls] == [4, 2]
    for conversations, sampling, use_tqdm in llm.calls:
        assert (sampling.temperature, sampling.max_tokens, use_tqdm) == (0.0, 7, False)
        for conversation in conversations:
            (turn,) = conversation
            assert turn["role"] == "user" and [p["type"] for p in turn["content"]] == ["image_pil", "text"]
            w, h = turn["content"][0]["image_pil"].size
            assert w * h <= 40 * 30
    sent = [c for conversations, _, _ in llm.calls for c in conversations]
    assert [c[0]["content"][1]["text"] for c in sent] == [r.text for r in requests]
    for result, conversation in zip(results, sent):
        words = len(conversation[0]["content"][1]["text"].split())
        assert (result.input_tokens, result.output_tokens, result.cost_cents) == (
            words + 100,
            len(result.text.split()) + 1,
            None,
        )
        assert result.text.startswith("A road seen in") and result.seconds > 0
    info = backend.info
    assert (info["backend"], info["gpus"], info["tensor_parallel_size"], info["model_type"], info["vllm"]) == (
        "vllm",
        2,
        2,
        "qwen2_5_vl",
        "0.32.0-fake",
    )
    assert info["engine"]["limit_mm_per_prompt"] == {"image": 1} and json.dumps(info)


def test_lightemma_run_with_the_vllm_backend_reasks_and_accounts_like_any_backend(
    fake_vllm, dataroot, tmp_path, capsys
):
    code = cli_main(
        [
            "run",
            "--backend",
            "vllm",
            "--model",
            "Qwen-2.5-VL-7B",
            "--dataroot",
            str(dataroot),
            "--version",
            "v1.0-mini",
            "--split",
            "all",
            "--limit",
            str(N_FRAMES),
            "--output",
            str(tmp_path),
            "--batch-size",
            "4",
            "--tensor-parallel-size",
            "1",
            "--no-progress",
        ]
    )
    assert code == 0, capsys.readouterr().err
    (run_dir,) = [p.parent for p in tmp_path.glob("*/*/manifest.json")]
    contents = read_run(run_dir)
    assert contents.manifest["backend"]["backend"] == "vllm"
    assert contents.manifest["backend"]["model"] == "Qwen/Qwen2.5-VL-7B-Instruct"  # the registry name's checkpoint
    (llm,) = FakeLLM.instances
    # stage-synchronous: scene ×4, intent ×4, actions ×4 (all bad), re-asked actions ×4 (all good)
    assert [len(c[0]) for c in llm.calls] == [4, 4, 4, 4]
    for record in contents.records.values():
        assert (record["status"], record["first_status"], record["n_attempts"]) == ("ok", "failed", 2)
        calls = [c for a in record["attempts"] for c in a["calls"]]
        assert [c["stage"] for c in calls] == ["scene", "intent", "actions", "actions"]
        assert record["input_tokens"] == sum(c["input_tokens"] for c in calls) > 400
        assert record["cost_cents"] is None and np.allclose(record["actions"][0], [5.0, 0.0])


def test_vllm_refuses_llama_3_2_vision_and_points_to_hf(fake_vllm, tmp_path):
    from lightemma.backends import create_backend

    with pytest.raises(UserError, match="--backend hf"):
        create_backend("llama-3.2-11b", backend="vllm")  # registry name -> meta-llama/Llama-3.2-11B-Vision-Instruct
    checkpoint = tmp_path / "my-finetune"
    checkpoint.mkdir()
    (checkpoint / "config.json").write_text(json.dumps({"model_type": "mllama"}))
    with pytest.raises(UserError, match="mllama.*--backend hf"):
        create_backend(str(checkpoint), backend="vllm")
    with pytest.raises(UserError, match="--backend hf"):  # caught from the engine's config too
        create_backend(str(tmp_path / "renamed-mllama"), backend="vllm")
    assert not [i for i in FakeLLM.instances if "Llama-3.2" in i.model or i.model == str(checkpoint)]


def test_a_failing_vllm_batch_gives_error_results(fake_vllm, images):
    backend = vllm_backend(batch_size=2)

    def broken(*args, **kwargs):
        raise RuntimeError("CUDA error: an illegal memory access was encountered")

    FakeLLM.instances[0].chat = broken
    results = answer(backend, requests_for(images)[:2], together=True)
    assert [(r.ok, r.error) for r in results] == [(False, "RuntimeError")] * 2
    assert "illegal memory access" in results[0].error_message


def test_vllm_counts_prompt_tokens_served_from_the_prefix_cache(fake_vllm, images):
    backend = vllm_backend(batch_size=8)
    first = requests_for(images[:2], stage="scene")
    second = requests_for(images[:2], stage="intent")

    async def main():
        await backend.generate(first)
        await backend.generate(second)
        await backend.aclose()

    asyncio.run(main())
    assert backend.stats["prefix_cached_tokens"] == 2 * 100 and backend.stats["batches"] == 2


def test_vllm_bad_options_and_missing_vllm_are_user_errors(monkeypatch):
    from lightemma.backends.vllm import VLLMBackend

    with pytest.raises(UserError, match="--tensor-parallel-size"):
        VLLMBackend("Qwen/Qwen2-VL-7B-Instruct", tensor_parallel_size=0)
    with pytest.raises(UserError, match="--gpu-memory-utilization"):
        VLLMBackend("Qwen/Qwen2-VL-7B-Instruct", gpu_memory_utilization=1.5)
    monkeypatch.setitem(sys.modules, "vllm", None)
    with pytest.raises(UserError, match=r"pip install 'lightemma\[vllm\]'"):
        VLLMBackend("Qwen/Qwen2-VL-7B-Instruct")


@pytest.mark.slow
@pytest.mark.gpu
def test_vllm_end_to_end_on_a_gpu(dataroot, tmp_path):
    """Only where vLLM is installed (its own environment, with a GPU): a tiny Qwen2-VL through `lightemma run`."""
    pytest.importorskip("vllm")
    path = build_tiny_model("qwen2_vl", tmp_path / "tiny", hidden_size=128, heads=2)
    code = cli_main(
        [
            "run",
            "--backend",
            "vllm",
            "--model",
            str(path),
            "--dataroot",
            str(dataroot),
            "--version",
            "v1.0-mini",
            "--split",
            "all",
            "--limit",
            str(N_FRAMES),
            "--output",
            str(tmp_path / "out"),
            "--max-tokens",
            "8",
            "--max-attempts",
            "2",
            "--gpu-memory-utilization",
            "0.3",
            "--no-progress",
        ]
    )
    assert code == 0
    (run_dir,) = [p.parent for p in (tmp_path / "out").glob("*/*/manifest.json")]
    records = list(read_run(run_dir).records.values())
    assert len(records) == N_FRAMES
    assert all(r["input_tokens"] > 0 and r["output_tokens"] > 0 and r["cost_cents"] is None for r in records)


@pytest.mark.slow
def test_a_batch_that_runs_out_of_gpu_memory_is_halved_until_it_fits(qwen2_vl, images):
    import torch

    requests = requests_for(images)[:5]
    alone = answer(hf(qwen2_vl, batch_size=1), requests)
    backend = hf(qwen2_vl, batch_size=5, batch_window=1.0)
    generate = backend._model.generate
    sizes = []

    def tight_memory(**inputs):
        sizes.append(inputs["input_ids"].shape[0])
        if inputs["input_ids"].shape[0] > 2:
            raise torch.cuda.OutOfMemoryError("CUDA out of memory. Tried to allocate 20.00 GiB")
        return generate(**inputs)

    backend._model.generate = tight_memory
    got = answer(backend, requests, together=True)
    assert sizes == [5, 2, 3, 1, 2]  # 5 -> 2 + 3 -> 2 + (1 + 2)
    assert backend.stats["oom_splits"] == 2 and backend.stats["batches"] == 1
    assert [(r.text, r.input_tokens, r.output_tokens) for r in got] == [
        (r.text, r.input_tokens, r.output_tokens) for r in alone
    ]


@pytest.mark.slow
def test_resume_rebuilds_the_hf_backend_from_the_manifest_and_redoes_frames_identically(
    taught, dataroot, tmp_path, capsys
):
    from lightemma.runs.store import FRAMES_FILE

    args = [
        "--dataroot",
        str(dataroot),
        "--version",
        "v1.0-mini",
        "--split",
        "all",
        "--limit",
        str(N_FRAMES),
        "--output",
        str(tmp_path),
        "--max-tokens",
        str(MAX_TOKENS),
        "--max-attempts",
        "1",
        "--no-progress",
    ]
    # exit 1: "Keep the lane." is a format error, so no frame is valid; the chain runs all three stages
    assert (
        cli_main(["run", "--backend", "hf", "--model", str(taught), "--batch-size", "2", "--dtype", "float32", *args])
        == 1
    )
    (run_dir,) = [p.parent for p in tmp_path.glob("*/*/manifest.json")]
    lines = (run_dir / FRAMES_FILE).read_text().splitlines(keepends=True)
    dropped = {json.loads(line)["frame_id"]: json.loads(line) for line in lines[2:]}
    (run_dir / FRAMES_FILE).write_text("".join(lines[:2]))
    assert (
        cli_main(["run", "--resume", str(run_dir), "--batch-size", "4", "--no-progress"]) == 2
    )  # from the manifest only
    assert "drop --batch-size" in capsys.readouterr().err
    assert cli_main(["run", "--resume", str(run_dir), "--no-progress"]) == 1, capsys.readouterr().err
    contents = read_run(run_dir)
    assert len(contents.records) == N_FRAMES and contents.complete
    assert contents.manifest["config"]["backend_options"] == {"batch_size": 2, "dtype": "float32"}
    for frame_id, before in dropped.items():
        again = contents.records[frame_id]
        assert before["scene_text"] == before["intent_text"] == before["answer"] == TAUGHT
        assert (again["scene_text"], again["intent_text"], again["answer"], again["input_tokens"]) == (
            before["scene_text"],
            before["intent_text"],
            before["answer"],
            before["input_tokens"],
        )


@pytest.mark.slow
def test_the_checkpoints_own_sampling_settings_do_not_change_greedy_answers(qwen2_vl, images, tmp_path):
    import shutil

    tuned = shutil.copytree(qwen2_vl, tmp_path / "tuned")
    settings = json.loads((tuned / "generation_config.json").read_text())
    settings.update(do_sample=True, temperature=0.7, top_k=3, top_p=0.5, repetition_penalty=3.0, no_repeat_ngram_size=1)
    (tuned / "generation_config.json").write_text(json.dumps(settings))
    requests = requests_for(images)[:3]
    plain = answer(hf(qwen2_vl), requests, together=True)
    backend = hf(tuned)
    assert [r.text for r in answer(backend, requests, together=True)] == [r.text for r in plain]
    assert backend.checkpoint_generation_config["repetition_penalty"] == 3.0  # it was read, and not used
    assert "not used" in backend.info["decoding"]
    # a repetition penalty or n-gram ban would have had something to act on: plain answers repeat tokens
    assert any(len(set(r.text)) < len(r.text) for r in plain)


# -- structured answers and the conversation chain on local backends ---------------------------------


def structured_requests(images, max_tokens=200):
    from lightemma.backends.structured import ACTIONS_SCHEMA

    return [
        ChatRequest(
            text=f"Predict the next 6 actions as JSON, v1, c1 … ({i})",
            stage="actions",
            frame_id=f"f{i}",
            image_path=p,
            params=GenerationParams(max_tokens=max_tokens),
            response_schema=ACTIONS_SCHEMA,
        )
        for i, p in enumerate(images[:3])
    ]


@pytest.mark.slow
def test_hf_answers_under_xgrammar_are_always_schema_valid_even_from_random_weights(tiny, images):
    """Random weights, greedy: without the grammar the answers are babble; with it every answer is the actions
    object, every number within the schema's bound, and parsing can fail only on plausibility, never on format."""
    from dataclasses import replace

    from lightemma import parse_actions
    from lightemma.backends.structured import MAGNITUDE

    family, path = tiny
    requests = structured_requests(images)
    backend = hf(path, batch_size=3)
    constrained = answer(backend, requests)
    free = answer(
        hf(path, batch_size=3),
        [replace(r, response_schema=None, params=GenerationParams(max_tokens=60)) for r in requests],
    )
    assert backend.structured_output()["mechanism"].startswith("xgrammar ")
    for result in constrained:
        assert result.ok and result.finish_reason == "stop", (family, result.text)
        value = json.loads(result.text)
        assert (
            list(value) == ["actions"]
            and len(value["actions"]) == 6
            and all(len(pair) == 2 for pair in value["actions"])
        )
        numbers = np.array(value["actions"], dtype=np.float64)
        assert np.isfinite(numbers).all() and (np.abs(numbers) <= MAGNITUDE).all()
        assert result.cached_input_tokens == 0  # transformers keeps no prefix cache
    parsed = parse_actions([r.text for r in constrained], mode="json")
    assert set(parsed.failure) <= {"", "implausible"}, (family, parsed.reason)
    for k, (reason, failure, result) in enumerate(zip(parsed.reason, parsed.failure, constrained)):
        if failure == "implausible":  # the reason names a value the model really wrote
            assert reason.split()[1] in result.text, (reason, result.text)
        else:  # read exactly as written
            assert np.array_equal(parsed.actions[k], np.array(json.loads(result.text)["actions"], dtype=np.float64))
    unconstrained = parse_actions([r.text or "" for r in free], mode="json")
    assert set(unconstrained.failure) <= {"format", "truncated"} and "" not in set(unconstrained.failure)


@pytest.mark.slow
def test_hf_takes_conversations_through_the_chat_template(qwen2_vl, images):
    """The conversation chain's requests: earlier turns as user/assistant messages, the image in the first only."""
    first = ChatRequest(
        text="Describe the scene.",
        stage="scene",
        frame_id="f0",
        image_path=images[0],
        params=GenerationParams(max_tokens=4),
    )
    later = ChatRequest(
        text="What should the car do?",
        stage="intent",
        frame_id="f0",
        image_path=images[0],
        params=GenerationParams(max_tokens=4),
        turns=(("Describe the scene.", "A quiet road."),),
    )
    from lightemma.backends.local import conversation

    backend = hf(qwen2_vl)
    chats = [
        backend._processor.apply_chat_template(
            conversation(r, {"type": "image"}), add_generation_prompt=True, tokenize=False
        )
        for r in (first, later)
    ]
    one, two = answer(backend, [first, later])
    assert chats[1].startswith(
        chats[0].removesuffix("<|im_start|>assistant\n")
    )  # the first request is the later's prefix
    assert chats[1].count("<|image_pad|>") == 1 and "<|im_start|>assistant\nA quiet road.<|im_end|>" in chats[1]
    assert two.input_tokens > one.input_tokens + 5


@pytest.mark.slow
def test_lightemma_run_with_hf_and_structured_answers_records_schema_valid_answers(taught, dataroot, tmp_path, capsys):
    from lightemma.backends.structured import MAGNITUDE

    code = cli_main(
        [
            "run",
            "--backend",
            "hf",
            "--model",
            str(taught),
            "--dataroot",
            str(dataroot),
            "--version",
            "v1.0-mini",
            "--split",
            "all",
            "--limit",
            "2",
            "--output",
            str(tmp_path),
            "--batch-size",
            "2",
            "--max-tokens",
            "160",
            "--max-attempts",
            "2",
            "--answer-format",
            "structured",
            "--no-progress",
        ]
    )
    capsys.readouterr()
    assert code in (0, 1)
    (run_dir,) = [p.parent for p in tmp_path.glob("*/*/manifest.json")]
    contents = read_run(run_dir)
    assert contents.manifest["structured_output"]["mechanism"].startswith("xgrammar")
    answers = [
        a
        for r in contents.records.values()
        for a in r["attempts"]
        if a["answer"] is not None and a["calls"][-1]["stage"] == "actions"
    ]
    assert answers
    for attempt in answers:
        value = json.loads(attempt["answer"])["actions"]
        assert len(value) == 6 and np.all(np.abs(np.array(value, dtype=float)) <= MAGNITUDE)
        assert attempt["status"] == "ok" or attempt["reason"].startswith(("speed", "curvature")), attempt["reason"]


def test_vllm_passes_the_actions_schema_as_structured_outputs_on_stage_3_only(fake_vllm, dataroot, tmp_path, capsys):
    from lightemma.backends.structured import ACTIONS_SCHEMA

    code = cli_main(
        [
            "run",
            "--backend",
            "vllm",
            "--model",
            "Qwen-2.5-VL-7B",
            "--dataroot",
            str(dataroot),
            "--version",
            "v1.0-mini",
            "--split",
            "all",
            "--limit",
            str(N_FRAMES),
            "--output",
            str(tmp_path),
            "--batch-size",
            "4",
            "--answer-format",
            "structured",
            "--no-progress",
        ]
    )
    assert code == 0, capsys.readouterr().err
    (llm,) = FakeLLM.instances
    for conversations, sampling, _ in llm.calls:
        is_actions = "v1, c1" in conversations[0][-1]["content"][-1]["text"]
        if is_actions:
            assert isinstance(sampling.structured_outputs, FakeStructuredOutputsParams)
            assert (
                sampling.structured_outputs.json == ACTIONS_SCHEMA.as_dict()
                and sampling.structured_outputs.disable_any_whitespace
            )
        else:
            assert sampling.structured_outputs is None
    (run_dir,) = [p.parent for p in tmp_path.glob("*/*/manifest.json")]
    contents = read_run(run_dir)
    assert "StructuredOutputsParams" in contents.manifest["structured_output"]["mechanism"]
    for record in contents.records.values():
        assert record["status"] == "ok" and json.loads(record["answer"])["actions"][0] == [5.0, 0.0]


def test_vllm_conversation_chain_and_cached_tokens_per_call(fake_vllm, dataroot, tmp_path, capsys):
    code = cli_main(
        [
            "run",
            "--backend",
            "vllm",
            "--model",
            "Qwen-2.5-VL-7B",
            "--dataroot",
            str(dataroot),
            "--version",
            "v1.0-mini",
            "--split",
            "all",
            "--limit",
            str(N_FRAMES),
            "--output",
            str(tmp_path),
            "--batch-size",
            "4",
            "--chain",
            "conversation",
            "--no-progress",
        ]
    )
    assert code == 0, capsys.readouterr().err
    (llm,) = FakeLLM.instances
    shapes = [[len(c) for c in conversations] for conversations, _, _ in llm.calls]
    assert shapes == [[1] * 4, [3] * 4, [5] * 4, [5] * 4]  # scene, intent, actions, the re-asked actions
    for conversations, _, _ in llm.calls:
        for conversation in conversations:
            kinds = [[p["type"] for p in turn["content"]] for turn in conversation]
            assert kinds[0] == ["image_pil", "text"] and all(k == ["text"] for k in kinds[1:])
            assert [t["role"] for t in conversation] == ["user", "assistant"] * (len(conversation) // 2) + ["user"]
    (run_dir,) = [p.parent for p in tmp_path.glob("*/*/manifest.json")]
    first_calls = []
    for record in read_run(run_dir).records.values():
        calls = [c for a in record["attempts"] for c in a["calls"]]
        # vLLM's num_cached_tokens per request: the image prefix once the frame's first request has been through
        assert [c["cached_input_tokens"] for c in calls[1:]] == [100, 100, 100] and calls[0]["cached_input_tokens"] in (
            0,
            100,
        )
        assert (
            record["cached_input_tokens"] == sum(c["cached_input_tokens"] for c in calls) and record["status"] == "ok"
        )
        first_calls.append(calls[0]["cached_input_tokens"])
    assert 0 in first_calls  # (frames whose image repeats an earlier frame's hit the cache from their first request)


def test_vllm_without_structured_outputs_is_refused_for_structured_answers(fake_vllm, tmp_path):
    del fake_vllm.sampling_params
    backend = vllm_backend()
    with pytest.raises(UserError, match="has no StructuredOutputsParams"):
        backend.structured_output()


# -- input ablations (--inputs) on the local backends ---------------------------------------------------


@pytest.mark.parametrize("inputs", ["no-image", "blank-image", "no-history"])
def test_vllm_is_shown_what_each_input_ablation_leaves(fake_vllm, dataroot, tmp_path, capsys, inputs):
    code = cli_main(
        [
            "run",
            "--backend",
            "vllm",
            "--model",
            "Qwen-2.5-VL-7B",
            "--dataroot",
            str(dataroot),
            "--version",
            "v1.0-mini",
            "--split",
            "all",
            "--limit",
            "2",
            "--output",
            str(tmp_path),
            "--batch-size",
            "2",
            "--answer-format",
            "structured",
            "--inputs",
            inputs,
            "--no-progress",
        ]
    )
    assert code == 0, capsys.readouterr().err
    (run_dir,) = [p.parent for p in tmp_path.glob("*/*/manifest.json")]
    contents = read_run(run_dir)
    assert contents.manifest["config"]["inputs"] == inputs
    frames = lightemma.load_frames(dataroot, "v1.0-mini", split="all")
    (llm,) = FakeLLM.instances
    conversations = [c for cs, _, _ in llm.calls for c in cs]
    assert len(conversations) >= 6
    histories = {lightemma.frames.format_history(f.history_actions) for f in frames.head(2)}
    for conversation in conversations:
        sent = [p["image_pil"] for turn in conversation for p in turn["content"] if p["type"] == "image_pil"]
        text = "\n".join(p["text"] for turn in conversation for p in turn["content"] if p["type"] == "text")
        if inputs == "no-image":
            assert sent == []
        else:
            (image,) = sent
            if inputs == "blank-image":
                assert image.size == (64, 48) and np.unique(np.asarray(image).reshape(-1, 3), axis=0).tolist() == [
                    [128, 128, 128]
                ]
            else:
                assert np.asarray(image).std() > 0  # the camera image itself
        if inputs == "no-history":
            assert not any(h in text for h in histories) and "past 3 seconds" not in text


@pytest.mark.slow
def test_hf_runs_each_image_ablation_end_to_end(qwen2_vl, dataroot, tmp_path):
    from lightemma.pipeline import run

    for inputs in ("no-image", "blank-image"):
        result = run(
            str(qwen2_vl),
            backend="hf",
            dataroot=dataroot,
            version="v1.0-mini",
            split="all",
            limit=1,
            output=tmp_path / inputs,
            max_tokens=4,
            max_attempts=1,
            inputs=inputs,
            progress=False,
            backend_options={"dtype": "float32", "device": "cpu"},
        )
        (record,) = read_run(result.run_dir).records.values()
        calls = [c for a in record["attempts"] for c in a["calls"]]
        assert calls and all(c["error"] is None and c["input_tokens"] > 0 for c in calls)
        assert result.manifest["config"]["inputs"] == inputs
    # the blank image costs the same image tokens as the photo (same size), no image costs none
    tokens = {i: read_run(next((tmp_path / i).glob("*/*"))).records for i in ("no-image", "blank-image")}
    first = {i: next(iter(r.values()))["attempts"][0]["calls"][0]["input_tokens"] for i, r in tokens.items()}
    assert first["blank-image"] > first["no-image"]
