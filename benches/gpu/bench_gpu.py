"""GPU bench of the ``hf`` backend through ``lightemma run``: random-weight models of the real architectures.

Run by ``benches/gpu/run.sh`` (on the GPU machine) or ``run.sh --tiny`` (a CPU, tiny configs, seconds).

What it measures, for Qwen2.5-VL-7B's architecture and then, if time remains, Qwen3-VL-8B's:

* **throughput** — ``lightemma run --backend hf`` over synthetic 1600 × 900 frames
  (``lightemma synth``) at batch size 1, 8 and 32 (frames in flight = batch size), bf16: frames/s
  and generated tokens/s over the run's wall time from the moment the model is ready to the end of
  the run (model initialisation excluded), and peak GPU memory (``torch.cuda.max_memory_allocated``);
* **agreement** — under greedy decoding, the fraction of frames whose three stage texts are identical
  when the frame ran alone (batch 1) and when it ran batched (8 and 32), in fp32 and in bf16.

How the model is made without downloading anything: the checkpoint folder holds only the
architecture's ``config.json`` (the published numbers, written below) and a processor: the family's
real image processor with the published pixel settings, and a byte-level BPE tokenizer trained here
on the prompt set, filled up to the architecture's vocabulary size. The bench hooks
``AutoModelForImageTextToText.from_pretrained`` for that folder only: the weights are initialised
randomly (seeded) directly on the GPU in the requested dtype (``from_config``). Everything else —
processor, chat template, micro-batching, the three-stage chain, the records — is ``lightemma run``'s
own path. A random model never ends an answer by itself, so every call generates exactly
``--max-new-tokens`` tokens, the last forced to be the end-of-turn token (``min_new_tokens`` +
``forced_eos_token_id``): each stage's text is passed on, every frame makes exactly three calls
(``--max-attempts 1``), and the work per call is the same at every batch size. Stage 3's random text
never parses, so every frame ends ``failed``: that is expected and not what is measured.

Results: ``OUT/gpu.json`` (rewritten after every step, so a killed bench keeps what it measured)
and ``OUT/gpu.md`` (the markdown tables). The bench stops itself before ``--deadline`` seconds.
"""

from __future__ import annotations

import argparse
import datetime
import gc
import json
import math
import os
import platform
import shutil
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

TINY_DIMS = {"hidden_size": 64, "heads": 4, "kv_heads": 2, "layers": 2, "vocab_size": 1024}

# The published architectures (Hugging Face config.json of Qwen/Qwen2.5-VL-7B-Instruct and
# Qwen/Qwen3-VL-8B-Instruct), written out so that nothing is downloaded.
ARCHITECTURES: dict[str, dict[str, Any]] = {
    "Qwen2.5-VL-7B": {
        "family": "qwen2_5_vl",
        "text": dict(
            vocab_size=152064,
            hidden_size=3584,
            intermediate_size=18944,
            num_hidden_layers=28,
            num_attention_heads=28,
            num_key_value_heads=4,
            max_position_embeddings=128000,
            rms_norm_eps=1e-6,
            hidden_act="silu",
            tie_word_embeddings=False,
            rope_parameters={"rope_type": "default", "rope_theta": 1000000.0, "mrope_section": [16, 24, 24]},
        ),
        "vision": dict(
            depth=32,
            hidden_size=1280,
            intermediate_size=3420,
            num_heads=16,
            in_channels=3,
            patch_size=14,
            spatial_merge_size=2,
            temporal_patch_size=2,
            window_size=112,
            fullatt_block_indexes=[7, 15, 23, 31],
            out_hidden_size=3584,
            hidden_act="silu",
            tokens_per_second=2,
        ),
        "image": dict(patch_size=14, merge_size=2, temporal_patch_size=2, min_pixels=3136, max_pixels=12845056),
    },
    "Qwen3-VL-8B": {
        "family": "qwen3_vl",
        "text": dict(
            vocab_size=151936,
            hidden_size=4096,
            intermediate_size=12288,
            num_hidden_layers=36,
            num_attention_heads=32,
            num_key_value_heads=8,
            head_dim=128,
            max_position_embeddings=262144,
            rms_norm_eps=1e-6,
            hidden_act="silu",
            tie_word_embeddings=False,
            rope_parameters={
                "rope_type": "default",
                "rope_theta": 5000000.0,
                "mrope_section": [24, 20, 20],
                "mrope_interleaved": True,
            },
        ),
        "vision": dict(
            depth=27,
            hidden_size=1152,
            intermediate_size=4304,
            num_heads=16,
            in_channels=3,
            patch_size=16,
            spatial_merge_size=2,
            temporal_patch_size=2,
            out_hidden_size=4096,
            num_position_embeddings=2304,
            deepstack_visual_indexes=[8, 16, 24],
            hidden_act="gelu_pytorch_tanh",
        ),
        "image": dict(patch_size=16, merge_size=2, temporal_patch_size=2, min_pixels=65536, max_pixels=16777216),
    },
}

# Qwen's special tokens and chat template (single user turns [image, text] and assistant turns), shared
# with the tests' tiny models
sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from tests.support.local_models import QWEN_SPECIALS, QWEN_TEMPLATE  # noqa: E402


def tiny_architecture(name: str) -> dict[str, Any]:
    """The same family and structure, shrunk so that a CPU runs it in milliseconds."""
    arch = json.loads(json.dumps(ARCHITECTURES[name]))
    d = TINY_DIMS
    half = d["hidden_size"] // d["heads"] // 2
    section = [half // 2, half // 4, half - half // 2 - half // 4]
    arch["text"].update(
        vocab_size=d["vocab_size"],
        hidden_size=d["hidden_size"],
        intermediate_size=2 * d["hidden_size"],
        num_hidden_layers=d["layers"],
        num_attention_heads=d["heads"],
        num_key_value_heads=d["kv_heads"],
        max_position_embeddings=8192,
    )
    arch["text"]["rope_parameters"]["mrope_section"] = section
    if "head_dim" in arch["text"]:
        arch["text"]["head_dim"] = d["hidden_size"] // d["heads"]
    arch["vision"].update(depth=2, hidden_size=32, intermediate_size=64, num_heads=2, out_hidden_size=d["hidden_size"])
    if "fullatt_block_indexes" in arch["vision"]:
        arch["vision"]["fullatt_block_indexes"] = [1]
    if "deepstack_visual_indexes" in arch["vision"]:
        arch["vision"].update(deepstack_visual_indexes=[0], num_position_embeddings=64)
    arch["image"]["max_pixels"] = 320 * 180
    return arch


# -- the checkpoint folder: config + processor, no weights -------------------------------------------------


def _corpus() -> list[str]:
    """Text the tokenizer learns its merges from: the prompt set's three stages, rendered."""
    from lightemma.prompts import load_prompt_set

    prompts = load_prompt_set()
    history = "[(4.512, 0.0), (4.6, -0.012), (4.7, 0.0), (5.0, 0.003), (5.1, 0.0), (5.25, 0.1)]"
    scene = "A straight road with two lanes; a white car ahead brakes at a red traffic light; pedestrians wait."
    return [
        prompts.render("scene"),
        prompts.render("intent", scene=scene, history=history),
        prompts.render("actions", scene=scene, history=history, intent="Slow down and stop at the light."),
    ] * 8


def build_tokenizer(vocab_size: int) -> Any:
    """Byte-level BPE (every byte is a token: any text round-trips) + Qwen's special tokens, ``vocab_size`` ids.

    The merges are learnt from the prompts (at most 4,000), and the vocabulary is filled up to the
    architecture's size with word tokens, so every id a random model emits decodes to text.
    """
    from tokenizers import Tokenizer, decoders, models, pre_tokenizers, trainers
    from transformers import PreTrainedTokenizerFast

    tok = Tokenizer(models.BPE())
    tok.pre_tokenizer = pre_tokenizers.ByteLevel(add_prefix_space=False)
    tok.decoder = decoders.ByteLevel()
    trainer = trainers.BpeTrainer(
        vocab_size=min(4000, vocab_size),
        special_tokens=QWEN_SPECIALS,
        show_progress=False,
        initial_alphabet=pre_tokenizers.ByteLevel.alphabet(),
    )
    tok.train_from_iterator(_corpus(), trainer=trainer)
    data = json.loads(tok.to_str())
    vocab = data["model"]["vocab"]
    next_id, i = max(vocab.values()) + 1, 0
    while next_id < vocab_size:
        n, word = i, ""
        while True:
            word = "abcdefghijklmnopqrstuvwxyz"[n % 26] + word
            n = n // 26 - 1
            if n < 0:
                break
        i += 1
        if "Ġ" + word not in vocab:
            vocab["Ġ" + word] = next_id
            next_id += 1
    tok = Tokenizer.from_str(json.dumps(data))
    return PreTrainedTokenizerFast(
        tokenizer_object=tok,
        bos_token=None,
        eos_token="<|im_end|>",
        pad_token="<|endoftext|>",
        unk_token=None,
        padding_side="left",
    )


def write_checkpoint(arch: dict[str, Any], path: Path) -> Path:
    """``config.json`` + processor files of ``arch`` in ``path`` (no weights: the bench's loader makes them)."""
    import transformers as tf

    tokenizer = build_tokenizer(arch["text"]["vocab_size"])
    ids = {
        name: tokenizer.convert_tokens_to_ids(tok)
        for name, tok in (
            ("image_token_id", "<|image_pad|>"),
            ("video_token_id", "<|video_pad|>"),
            ("vision_start_token_id", "<|vision_start|>"),
            ("vision_end_token_id", "<|vision_end|>"),
        )
    }
    eos, pad = tokenizer.convert_tokens_to_ids("<|im_end|>"), tokenizer.convert_tokens_to_ids("<|endoftext|>")
    text = {**arch["text"], "eos_token_id": eos, "pad_token_id": pad, "bos_token_id": None}
    if arch["family"] == "qwen2_5_vl":
        config = tf.Qwen2_5_VLConfig(text_config=text, vision_config=arch["vision"], **ids)
        processor_cls, video_cls = tf.Qwen2_5_VLProcessor, tf.Qwen2VLVideoProcessor
    else:
        config = tf.Qwen3VLConfig(text_config=text, vision_config=arch["vision"], **ids)
        processor_cls, video_cls = tf.Qwen3VLProcessor, tf.Qwen3VLVideoProcessor
    config.save_pretrained(path)
    tf.GenerationConfig(eos_token_id=eos, pad_token_id=pad).save_pretrained(path)
    image = arch["image"]
    image_processor = tf.Qwen2VLImageProcessor(**image)
    video = video_cls(
        patch_size=image["patch_size"], temporal_patch_size=image["temporal_patch_size"], merge_size=image["merge_size"]
    )
    processor_cls(
        image_processor=image_processor, tokenizer=tokenizer, video_processor=video, chat_template=QWEN_TEMPLATE
    ).save_pretrained(path)
    return path


class RandomWeights:
    """Hooks ``AutoModelForImageTextToText.from_pretrained`` for the bench's folders: random weights, made on the device.

    One model per (folder, dtype) is kept while it is in use, so that the batch sizes share it;
    :meth:`ready` is when the last load returned (the start of a measured run).
    """

    def __init__(self, device: str, seed: int = 0) -> None:
        import transformers

        self.device, self.seed = device, seed
        self.folders: set[str] = set()
        self.models: dict[tuple[str, Any], Any] = {}
        self.init_seconds: dict[tuple[str, str], float] = {}
        self.ready = 0.0
        auto = transformers.AutoModelForImageTextToText
        original = auto.from_pretrained.__func__
        hook = self

        def from_pretrained(cls, name, *args, **kwargs):
            key = os.path.abspath(str(name))
            if key not in hook.folders:
                return original(cls, name, *args, **kwargs)
            model = hook.model(key, kwargs.get("dtype"))
            hook.ready = time.perf_counter()
            return model

        auto.from_pretrained = classmethod(from_pretrained)

    def model(self, folder: str, dtype: Any) -> Any:
        import torch
        import transformers

        key = (folder, dtype)
        if key not in self.models:
            start = time.perf_counter()
            config = transformers.AutoConfig.from_pretrained(folder)
            torch.manual_seed(self.seed)
            with torch.device(self.device):
                model = transformers.AutoModelForImageTextToText.from_config(config, dtype=dtype)
            model.generation_config = transformers.GenerationConfig.from_pretrained(folder)
            model.eval()
            _force_full_length(model)
            if self.device.startswith("cuda"):
                torch.cuda.synchronize()
            self.init_seconds[(folder, str(dtype).removeprefix("torch."))] = time.perf_counter() - start
            self.models[key] = model
        return self.models[key]

    def free(self) -> None:
        import torch

        self.models.clear()
        gc.collect()
        if torch.cuda.is_available():
            torch.cuda.empty_cache()


def _force_full_length(model: Any) -> None:
    """Every ``generate`` makes exactly ``max_new_tokens`` tokens, the last the end-of-turn token."""
    generate = model.generate

    def full_length(*args, **kwargs):
        n, eos = kwargs["max_new_tokens"], kwargs["eos_token_id"]
        return generate(*args, **kwargs, min_new_tokens=n - 1, forced_eos_token_id=eos)

    model.generate = full_length


# -- one measured run ----------------------------------------------------------------------------------------


def lightemma_run(
    hook: RandomWeights,
    folder: Path,
    dataroot: Path,
    out: Path,
    *,
    batch: int,
    frames: int,
    dtype: str,
    max_new_tokens: int,
) -> dict[str, Any]:
    """``lightemma run --backend hf`` over the first ``frames`` frames; throughput and texts from its records."""
    import torch

    from lightemma.cli import main as cli_main
    from lightemma.runs.store import find_run_dirs, read_run

    on_gpu = hook.device.startswith("cuda")
    if on_gpu:
        torch.cuda.synchronize()
        torch.cuda.reset_peak_memory_stats()
    hook.ready = 0.0
    argv = [
        "run",
        "--backend",
        "hf",
        "--model",
        str(folder),
        "--dataroot",
        str(dataroot),
        "--version",
        "v1.0-mini",
        "--split",
        "all",
        "--limit",
        str(frames),
        "--batch-size",
        str(batch),
        "--concurrency",
        str(batch),
        "--max-tokens",
        str(max_new_tokens),
        "--max-attempts",
        "1",
        "--temperature",
        "0",
        "--dtype",
        dtype,
        "--device",
        hook.device,
        "--output",
        str(out),
        "--no-progress",
    ]
    code = cli_main(argv)
    end = time.perf_counter()
    (run_dir,) = find_run_dirs(out)
    records = list(read_run(run_dir).records.values())
    calls = [c for r in records for a in r["attempts"] for c in a["calls"]]
    if len(records) != frames or len(calls) != 3 * frames or any(c.get("error") for c in calls):
        raise RuntimeError(
            f"lightemma run (exit {code}) recorded {len(records)} frame(s) and {len(calls)} call(s) "
            f"for {frames} frames × 3 stages; first error: "
            f"{next((c.get('error_message') for c in calls if c.get('error')), None)}"
        )
    wall = end - hook.ready
    out_tokens = sum(int(c["output_tokens"]) for c in calls)
    return {
        "dtype": dtype,
        "batch_size": batch,
        "frames": frames,
        "calls": len(calls),
        "wall_s": round(wall, 3),
        "frames_per_s": round(frames / wall, 4),
        "generated_tokens": out_tokens,
        "generated_tokens_per_s": round(out_tokens / wall, 2),
        "input_tokens_per_call": round(sum(int(c["input_tokens"]) for c in calls) / len(calls), 1),
        "peak_gpu_gib": round(torch.cuda.max_memory_allocated() / 2**30, 2) if on_gpu else None,
        "texts": {r["frame_id"]: [c["text"] for c in r["attempts"][0]["calls"]] for r in records},
    }


def agreement(single: dict[str, Any], batched: dict[str, Any]) -> dict[str, Any]:
    """Frames (and stage calls) whose texts are identical alone and batched, over the frames both ran."""
    common = [f for f in single["texts"] if f in batched["texts"]]
    same_calls = sum(a == b for f in common for a, b in zip(single["texts"][f], batched["texts"][f]))
    same_frames = sum(single["texts"][f] == batched["texts"][f] for f in common)
    return {
        "dtype": single["dtype"],
        "single": single["batch_size"],
        "batched": batched["batch_size"],
        "frames": len(common),
        "frames_identical": same_frames,
        "calls_identical": same_calls,
        "calls": 3 * len(common),
        "rate": round(same_frames / len(common), 4) if common else None,
    }


# -- the whole bench -----------------------------------------------------------------------------------------


class Deadline:
    """Seconds left before ``limit``; a watchdog ends the process (results already written) 20 s after it."""

    def __init__(self, limit: float, on_expiry) -> None:
        self.start, self.limit = time.perf_counter(), limit

        def watchdog():
            time.sleep(max(0.0, limit + 20))
            on_expiry()
            os._exit(3)

        threading.Thread(target=watchdog, daemon=True, name="bench-deadline").start()

    def left(self) -> float:
        return self.limit - (time.perf_counter() - self.start)


def environment(device: str) -> dict[str, Any]:
    import torch
    import transformers

    gpu = torch.cuda.get_device_name(0) if device.startswith("cuda") else None
    return {
        "date": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC"),
        "device": gpu or f"CPU ({platform.machine()}, {os.cpu_count()} cores)",
        "python": platform.python_version(),
        "torch": torch.__version__,
        "transformers": transformers.__version__,
    }


def markdown(result: dict[str, Any]) -> str:
    env = result["environment"]
    lines = [
        f"GPU bench ({'tiny configs, CPU' if result['tiny'] else 'random weights, real architectures'}): "
        f"{env['device']}, {env['date']}; torch {env['torch']}, transformers {env['transformers']}; "
        f"{result['image_size'][0]}×{result['image_size'][1]} synthetic frames, {result['max_new_tokens']} new tokens "
        "per call, 3 calls per frame",
        "",
        "| architecture | dtype | batch | frames | frames/s | generated tokens/s | input tokens/call | peak GPU GiB |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, arch in result["architectures"].items():
        for r in arch["runs"]:
            lines.append(
                f"| {name} | {r['dtype']} | {r['batch_size']} | {r['frames']} | {r['frames_per_s']:.3f} | "
                f"{r['generated_tokens_per_s']:.1f} | {r['input_tokens_per_call']:.0f} | {r['peak_gpu_gib'] if r['peak_gpu_gib'] is not None else '—'} |"
            )
    lines += [
        "",
        "| architecture | dtype | batch 1 vs | frames | frames identical | stage calls identical |",
        "|---|---|---|---|---|---|",
    ]
    for name, arch in result["architectures"].items():
        for a in arch["agreement"]:
            lines.append(
                f"| {name} | {a['dtype']} | {a['batched']} | {a['frames']} | {a['frames_identical']} | "
                f"{a['calls_identical']}/{a['calls']} |"
            )
    if result["skipped"]:
        lines += ["", "Not measured (time): " + "; ".join(result["skipped"])]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", required=True, type=Path)
    parser.add_argument("--tiny", action="store_true", help="tiny configs of the same architectures, on the CPU")
    parser.add_argument("--deadline", type=float, default=450.0, help="seconds; no new step starts that would pass it")
    parser.add_argument("--max-new-tokens", type=int, default=None, help="per call (default 32; 8 with --tiny)")
    parser.add_argument("--batch-sizes", type=int, nargs="+", default=[1, 8, 32])
    parser.add_argument("--architectures", nargs="+", default=list(ARCHITECTURES), choices=list(ARCHITECTURES))
    args = parser.parse_args(argv)
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    os.environ.setdefault("LITELLM_LOCAL_MODEL_COST_MAP", "True")
    import torch

    if args.tiny:
        torch.set_num_threads(1)
    device = "cpu" if args.tiny or not torch.cuda.is_available() else "cuda:0"
    if not args.tiny and device == "cpu":
        print("bench_gpu: no CUDA device; pass --tiny for the CPU check", file=sys.stderr)
        return 2
    max_new = args.max_new_tokens or (8 if args.tiny else 32)
    image_size = (320, 180) if args.tiny else (1600, 900)
    sizes = sorted(set(args.batch_sizes))
    # each stage runs at least two full batches (one with --tiny, to stay within seconds)
    frames_for = {b: max(2, b) if args.tiny else max(4, 2 * b) for b in sizes}
    agree_frames = 2 if args.tiny else 4  # fp32 agreement: batch 1 and the second batch size over the same frames
    args.out.mkdir(parents=True, exist_ok=True)
    result: dict[str, Any] = {
        "tiny": args.tiny,
        "environment": environment(device),
        "max_new_tokens": max_new,
        "image_size": list(image_size),
        "architectures": {},
        "skipped": [],
        "errors": [],
    }

    def save() -> None:
        result["elapsed_s"] = round(time.perf_counter() - deadline.start, 1)
        for path, text in (
            (args.out / "gpu.json", json.dumps(result, indent=1) + "\n"),
            (args.out / "gpu.md", markdown(result)),
        ):
            tmp = path.with_suffix(path.suffix + ".tmp")
            tmp.write_text(text, encoding="utf-8")
            os.replace(tmp, path)

    deadline = Deadline(args.deadline, save)
    work = Path(tempfile.mkdtemp(prefix="lightemma-gpu-bench-"))
    try:
        return _bench(args, result, save, deadline, work, device, max_new, image_size, sizes, frames_for, agree_frames)
    finally:
        shutil.rmtree(work, ignore_errors=True)


def _bench(args, result, save, deadline, work, device, max_new, image_size, sizes, frames_for, agree_frames) -> int:
    import lightemma.synth

    start = time.perf_counter()
    n_frames = max(frames_for.values())
    dataroot = lightemma.synth.write_dataset(
        work / "data", scenes=math.ceil(n_frames / 16), keyframes=30, image_size=image_size, sweeps=False
    )
    result["synth_s"] = round(time.perf_counter() - start, 1)
    hook = RandomWeights(device)
    step_seconds: list[float] = []

    def step(label: str, fn):
        """Run ``fn`` unless the slowest step so far would not fit in the time left."""
        if deadline.left() < (max(step_seconds) if step_seconds else 0.0) * 1.5:
            result["skipped"].append(label)
            return None
        t0 = time.perf_counter()
        try:
            return fn()
        except Exception as exc:  # noqa: BLE001 - recorded in gpu.json; the bench goes on with the next step
            result["errors"].append(f"{label}: {type(exc).__name__}: {exc}"[:600])
            return None
        finally:
            step_seconds.append(time.perf_counter() - t0)
            save()

    for name in args.architectures:
        arch = tiny_architecture(name) if args.tiny else ARCHITECTURES[name]
        folder = write_checkpoint(arch, work / name)
        hook.folders.add(os.path.abspath(folder))
        entry: dict[str, Any] = {
            "config": {"text": arch["text"], "vision": arch["vision"], "image": arch["image"]},
            "runs": [],
            "agreement": [],
        }
        result["architectures"][name] = entry
        for dtype, batch_sizes, frames in (("bfloat16", sizes, frames_for), ("float32", sizes[:2], None)):
            by_size: dict[int, dict[str, Any]] = {}
            if frames:  # warm-up (kernels, allocator, processor): one frame, not measured
                step(
                    f"{name} {dtype} warm-up",
                    lambda: lightemma_run(
                        hook,
                        folder,
                        dataroot,
                        work / f"runs-{name}-{dtype}-warmup",
                        batch=1,
                        frames=1,
                        dtype=dtype,
                        max_new_tokens=max_new,
                    ),
                )
            for b in batch_sizes:
                n = frames[b] if frames else agree_frames * (1 if b == sizes[0] else 2)
                run = step(
                    f"{name} {dtype} batch {b}",
                    lambda b=b, n=n: lightemma_run(
                        hook,
                        folder,
                        dataroot,
                        work / f"runs-{name}-{dtype}-{b}",
                        batch=b,
                        frames=n,
                        dtype=dtype,
                        max_new_tokens=max_new,
                    ),
                )
                if run is None:
                    continue
                if not entry.get("parameters"):
                    model = next(iter(hook.models.values()))
                    entry["parameters"] = sum(p.numel() for p in model.parameters())
                by_size[b] = run
                if frames:  # the bf16 runs are the throughput table; fp32 only feeds agreement
                    entry["runs"].append({k: v for k, v in run.items() if k != "texts"})
                if b != sizes[0] and sizes[0] in by_size:
                    entry["agreement"].append(agreement(by_size[sizes[0]], run))
            entry["init_s"] = {
                d: round(s, 1) for (f, d), s in hook.init_seconds.items() if f == os.path.abspath(folder)
            }
            hook.free()
            save()
    save()
    print(markdown(result))
    return 1 if result["errors"] else 0


if __name__ == "__main__":
    sys.exit(main())
