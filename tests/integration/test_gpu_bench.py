"""benches/gpu/bench_gpu.py builds the real architectures (checked on the meta device: no memory, no download).

The bench itself runs on the GPU machine (benches/gpu/run.sh) and, with tiny configs, in CI
(``bash benches/gpu/run.sh --tiny`` in .ci/run); these tests pin what the GPU figures would stand on.
"""

from __future__ import annotations

import pytest

from benches.gpu import bench_gpu

pytestmark = pytest.mark.slow  # every test here is heavy (the slow marker: pyproject.toml)

# parameter counts of the published checkpoints (safetensors metadata of Qwen/Qwen2.5-VL-7B-Instruct and
# Qwen/Qwen3-VL-8B-Instruct on the Hugging Face hub)
PUBLISHED = {"Qwen2.5-VL-7B": 8_292_166_656, "Qwen3-VL-8B": 8_767_123_696}


@pytest.fixture(scope="module", params=list(bench_gpu.ARCHITECTURES))
def checkpoint(request, tmp_path_factory):
    name = request.param
    return name, bench_gpu.write_checkpoint(bench_gpu.ARCHITECTURES[name], tmp_path_factory.mktemp(name))


def test_the_written_architecture_has_the_published_parameter_count(checkpoint):
    import torch
    import transformers

    name, folder = checkpoint
    config = transformers.AutoConfig.from_pretrained(folder)
    with torch.device("meta"):
        model = transformers.AutoModelForImageTextToText.from_config(config)
    assert sum(p.numel() for p in model.parameters()) == PUBLISHED[name]


def test_the_tokenizer_decodes_every_id_and_the_processor_sees_a_1600x900_frame_as_the_real_one(checkpoint):
    import numpy as np
    import transformers
    from PIL import Image

    name, folder = checkpoint
    arch = bench_gpu.ARCHITECTURES[name]
    processor = transformers.AutoProcessor.from_pretrained(folder)
    assert len(processor.tokenizer) == arch["text"]["vocab_size"]
    assert all(processor.tokenizer.decode([i]) for i in range(1000, arch["text"]["vocab_size"], 7919))
    frame = Image.fromarray(np.zeros((900, 1600, 3), dtype=np.uint8))
    turn = [{"role": "user", "content": [{"type": "image"}, {"type": "text", "text": "Describe."}]}]
    text = processor.apply_chat_template(turn, add_generation_prompt=True, tokenize=False)
    ids = processor(text=[text], images=[[frame]], return_tensors="pt")["input_ids"][0].tolist()
    unit = arch["image"]["patch_size"] * arch["image"]["merge_size"]  # pixels per image token side
    expected = round(900 / unit) * round(1600 / unit)  # the processor's smart resize: 32 x 57 for Qwen2.5-VL
    assert ids.count(processor.tokenizer.convert_tokens_to_ids("<|image_pad|>")) == expected


def test_agreement_counts_frames_and_stage_calls_over_the_frames_both_ran():
    single = {"dtype": "float32", "batch_size": 1, "texts": {"a": ["x", "y", "z"], "b": ["x", "y", "z"]}}
    batched = {
        "dtype": "float32",
        "batch_size": 8,
        "texts": {"a": ["x", "y", "z"], "b": ["x", "q", "z"], "c": ["?"] * 3},
    }
    got = bench_gpu.agreement(single, batched)
    assert (got["frames"], got["frames_identical"], got["calls_identical"], got["calls"], got["rate"]) == (
        2,
        1,
        5,
        6,
        0.5,
    )
