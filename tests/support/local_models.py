"""Tiny random-weight vision-language checkpoints, built fully offline, for the local backend tests.

Each builder writes a directory that ``AutoModelForImageTextToText.from_pretrained``
and ``AutoProcessor.from_pretrained`` load exactly as they load a real checkpoint:
the real model and processor classes of the family (Qwen2-VL, Qwen2.5-VL,
Qwen3-VL, Mllama, Llama-4), a byte-level BPE tokenizer trained here on a few sentences
(every byte is a token, so any text round-trips) with the family's special
tokens, the family's chat-template shape, and tiny dimensions (hidden size 32 by default,
one or two layers, one vision block, 8-16 px patches) so that each model has a
few hundred thousand parameters and generates in milliseconds on a CPU.

The weights are random (seeded), so the models babble: that is what the tests
want, to exercise format errors and re-asks. Babble never ends before the output
limit, so every answer is truncated; :func:`teach_to_answer` trains a tiny model
for a few dozen steps to answer every prompt with one short sentence and an
end-of-turn token, for tests that need answers that end (the chain through all
three stages, batching per stage, resume).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

# Words the tokenizer learns merges from: some of the prompts' vocabulary, so prompts are not one token per byte.
_CORPUS = [
    "You are an autonomous driving labeller looking at the front camera image of the ego vehicle.",
    "Describe the vehicles, pedestrians, lane markings, traffic lights and other relevant objects.",
    "Given the scene description and the past speeds and curvatures, predict the next 6 steps.",
    "speed curvature [(5.0, 0.0), (5.1, 0.01), (5.2, -0.02)] m/s 1/m turning left right lane",
] * 4

QWEN_SPECIALS = [
    "<|endoftext|>",
    "<|im_start|>",
    "<|im_end|>",
    "<|vision_start|>",
    "<|vision_end|>",
    "<|image_pad|>",
    "<|video_pad|>",
]
LLAMA_SPECIALS = [
    "<|begin_of_text|>",
    "<|end_of_text|>",
    "<|start_header_id|>",
    "<|end_header_id|>",
    "<|eot_id|>",
    "<|finetune_right_pad_id|>",
    "<|python_tag|>",
    "<|image|>",
]

LLAMA4_SPECIALS = [
    "<|begin_of_text|>",
    "<|end_of_text|>",
    "<|header_start|>",
    "<|header_end|>",
    "<|eot|>",
    "<|finetune_right_pad|>",
    "<|image_start|>",
    "<|image_end|>",
    "<|image|>",
    "<|patch|>",
    "<|tile_x_separator|>",
    "<|tile_y_separator|>",
]

# The families' chat templates, reduced to what a single user turn of [image, text] needs (plus system/assistant turns).
QWEN_TEMPLATE = (
    "{% for message in messages %}<|im_start|>{{ message['role'] }}\n"
    "{% if message['content'] is string %}{{ message['content'] }}"
    "{% else %}{% for part in message['content'] %}"
    "{% if part['type'] == 'image' %}<|vision_start|><|image_pad|><|vision_end|>"
    "{% elif part['type'] == 'text' %}{{ part['text'] }}{% endif %}"
    "{% endfor %}{% endif %}<|im_end|>\n{% endfor %}"
    "{% if add_generation_prompt %}<|im_start|>assistant\n{% endif %}"
)
LLAMA_TEMPLATE = (
    "{{ bos_token }}{% for message in messages %}<|start_header_id|>{{ message['role'] }}<|end_header_id|>\n\n"
    "{% if message['content'] is string %}{{ message['content'] }}"
    "{% else %}{% for part in message['content'] %}"
    "{% if part['type'] == 'image' %}<|image|>{% elif part['type'] == 'text' %}{{ part['text'] }}{% endif %}"
    "{% endfor %}{% endif %}<|eot_id|>{% endfor %}"
    "{% if add_generation_prompt %}<|start_header_id|>assistant<|end_header_id|>\n\n{% endif %}"
)

LLAMA4_TEMPLATE = (
    LLAMA_TEMPLATE.replace("<|start_header_id|>", "<|header_start|>")
    .replace("<|end_header_id|>", "<|header_end|>")
    .replace("<|eot_id|>", "<|eot|>")
)


def byte_level_tokenizer(specials: list[str], *, bos: str | None, eos: str, pad: str, vocab_size: int = 384):
    """A ``PreTrainedTokenizerFast``: byte-level BPE (all 256 bytes + a few merges) plus ``specials``."""
    from tokenizers import Tokenizer, decoders, models, pre_tokenizers, trainers
    from transformers import PreTrainedTokenizerFast

    tok = Tokenizer(models.BPE())
    tok.pre_tokenizer = pre_tokenizers.ByteLevel(add_prefix_space=False)
    tok.decoder = decoders.ByteLevel()
    trainer = trainers.BpeTrainer(
        vocab_size=vocab_size,
        special_tokens=specials,
        show_progress=False,
        initial_alphabet=pre_tokenizers.ByteLevel.alphabet(),
    )
    tok.train_from_iterator(_CORPUS, trainer=trainer)
    return PreTrainedTokenizerFast(
        tokenizer_object=tok, bos_token=bos, eos_token=eos, pad_token=pad, unk_token=None, padding_side="left"
    )


def _qwen_tokenizer():
    return byte_level_tokenizer(QWEN_SPECIALS, bos=None, eos="<|im_end|>", pad="<|endoftext|>")


def _ids(tokenizer, *tokens: str) -> list[int]:
    return [tokenizer.convert_tokens_to_ids(t) for t in tokens]


def _qwen_image_processor(patch: int, *, max_pixels: int = 64 * 64):
    from transformers import Qwen2VLImageProcessor

    return Qwen2VLImageProcessor(
        patch_size=patch, temporal_patch_size=2, merge_size=2, min_pixels=(2 * patch) ** 2, max_pixels=max_pixels
    )


def _qwen_video_processor(family: str, patch: int):
    if family == "qwen3_vl":
        from transformers import Qwen3VLVideoProcessor as cls
    else:
        from transformers import Qwen2VLVideoProcessor as cls
    return cls(patch_size=patch, temporal_patch_size=2, merge_size=2)


def _text(tokenizer, dims: dict[str, int], **extra):
    """Tiny decoder dimensions shared by the families (a few hundred thousand parameters)."""
    eos, pad = _ids(tokenizer, tokenizer.eos_token, tokenizer.pad_token)
    hidden, heads = dims["hidden_size"], dims["heads"]
    return dict(
        vocab_size=len(tokenizer),
        hidden_size=hidden,
        intermediate_size=2 * hidden,
        num_hidden_layers=2,
        num_attention_heads=heads,
        num_key_value_heads=max(1, heads // 2),
        max_position_embeddings=4096,
        bos_token_id=tokenizer.bos_token_id,
        eos_token_id=eos,
        pad_token_id=pad,
        **extra,
    )


def _mrope(dims: dict[str, int], **extra) -> dict[str, object]:
    """Multimodal RoPE over (time, height, width): the sections split half the head dimension."""
    half = dims["hidden_size"] // dims["heads"] // 2
    return {
        "rope_type": "default",
        "rope_theta": 10000.0,
        "mrope_section": [half // 2, half // 4, half - half // 2 - half // 4],
        **extra,
    }


def _vision_width(dims: dict[str, int]) -> int:
    """The vision tower's width: 32, or 64 (head dimension 32) beside a language model wider than 64."""
    return 32 if dims["hidden_size"] <= 64 else 64


def _qwen_special_ids(tokenizer) -> dict[str, int]:
    image, video, start, end = _ids(tokenizer, "<|image_pad|>", "<|video_pad|>", "<|vision_start|>", "<|vision_end|>")
    return dict(image_token_id=image, video_token_id=video, vision_start_token_id=start, vision_end_token_id=end)


def _build_qwen2_vl(tokenizer, dims):
    from transformers import Qwen2VLConfig, Qwen2VLForConditionalGeneration

    patch = 8
    config = Qwen2VLConfig(
        text_config=_text(tokenizer, dims, rope_parameters=_mrope(dims)),
        vision_config=dict(
            depth=1,
            embed_dim=_vision_width(dims),
            hidden_size=dims["hidden_size"],
            num_heads=2,
            mlp_ratio=2,
            patch_size=patch,
            spatial_merge_size=2,
            temporal_patch_size=2,
        ),
        **_qwen_special_ids(tokenizer),
    )
    return Qwen2VLForConditionalGeneration(config), patch


def _build_qwen2_5_vl(tokenizer, dims):
    from transformers import Qwen2_5_VLConfig, Qwen2_5_VLForConditionalGeneration

    patch = 8
    config = Qwen2_5_VLConfig(
        text_config=_text(tokenizer, dims, rope_parameters=_mrope(dims)),
        vision_config=dict(
            depth=1,
            hidden_size=_vision_width(dims),
            intermediate_size=2 * _vision_width(dims),
            num_heads=2,
            patch_size=patch,
            spatial_merge_size=2,
            temporal_patch_size=2,
            out_hidden_size=dims["hidden_size"],
            window_size=32,
            fullatt_block_indexes=[0],
        ),
        **_qwen_special_ids(tokenizer),
    )
    return Qwen2_5_VLForConditionalGeneration(config), patch


def _build_qwen3_vl(tokenizer, dims):
    from transformers import Qwen3VLConfig, Qwen3VLForConditionalGeneration

    patch = 8
    config = Qwen3VLConfig(
        text_config=_text(
            tokenizer,
            dims,
            head_dim=dims["hidden_size"] // dims["heads"],
            rope_parameters=_mrope(dims, mrope_interleaved=True),
        ),
        vision_config=dict(
            depth=1,
            hidden_size=_vision_width(dims),
            intermediate_size=2 * _vision_width(dims),
            num_heads=2,
            patch_size=patch,
            spatial_merge_size=2,
            temporal_patch_size=2,
            out_hidden_size=dims["hidden_size"],
            num_position_embeddings=64,
            deepstack_visual_indexes=[0],
        ),
        **_qwen_special_ids(tokenizer),
    )
    return Qwen3VLForConditionalGeneration(config), patch


def _qwen_saver(build: Callable, family: str) -> Callable[[Path, dict[str, int]], None]:
    def save(path: Path, dims: dict[str, int]) -> None:
        tokenizer = _qwen_tokenizer()
        model, patch = build(tokenizer, dims)
        from transformers import Qwen2_5_VLProcessor, Qwen2VLProcessor, Qwen3VLProcessor

        cls = {"qwen2_vl": Qwen2VLProcessor, "qwen2_5_vl": Qwen2_5_VLProcessor, "qwen3_vl": Qwen3VLProcessor}[family]
        processor = cls(
            image_processor=_qwen_image_processor(patch),
            tokenizer=tokenizer,
            video_processor=_qwen_video_processor(family, patch),
            chat_template=QWEN_TEMPLATE,
        )
        _save(model, processor, path)

    return save


def _save_mllama(path: Path, dims: dict[str, int]) -> None:
    from transformers import MllamaConfig, MllamaForConditionalGeneration, MllamaImageProcessor, MllamaProcessor

    tokenizer = byte_level_tokenizer(
        LLAMA_SPECIALS, bos="<|begin_of_text|>", eos="<|eot_id|>", pad="<|finetune_right_pad_id|>"
    )
    tile = 32
    text = _text(
        tokenizer, dims, cross_attention_layers=[1], rope_parameters={"rope_type": "default", "rope_theta": 10000.0}
    )
    config = MllamaConfig(
        text_config=text,
        vision_config=dict(
            hidden_size=16,
            num_hidden_layers=1,
            num_global_layers=1,
            attention_heads=2,
            intermediate_size=32,
            vision_output_dim=32,
            image_size=tile,
            patch_size=8,
            max_num_tiles=2,
            intermediate_layers_indices=[0],
            supported_aspect_ratios=[[1, 1], [1, 2], [2, 1]],
        ),
        image_token_index=tokenizer.convert_tokens_to_ids("<|image|>"),
    )
    # vision_output_dim = hidden_size * (1 + len(intermediate_layers_indices))
    model = MllamaForConditionalGeneration(config)
    image_processor = MllamaImageProcessor(size={"height": tile, "width": tile}, max_image_tiles=2)
    processor = MllamaProcessor(image_processor=image_processor, tokenizer=tokenizer, chat_template=LLAMA_TEMPLATE)
    _save(model, processor, path)


def _save_llama4(path: Path, dims: dict[str, int]) -> None:
    from transformers import Llama4Config, Llama4ForConditionalGeneration, Llama4ImageProcessor, Llama4Processor

    tokenizer = byte_level_tokenizer(
        LLAMA4_SPECIALS, bos="<|begin_of_text|>", eos="<|eot|>", pad="<|finetune_right_pad|>"
    )
    tile, patch = 32, 8
    hidden, heads = dims["hidden_size"], dims["heads"]
    text = _text(
        tokenizer,
        dims,
        head_dim=hidden // heads,
        intermediate_size_mlp=2 * hidden,
        num_local_experts=2,
        num_experts_per_tok=1,
        interleave_moe_layer_step=2,
        rope_parameters={"rope_type": "default", "rope_theta": 10000.0},
    )
    boi, eoi, image = _ids(tokenizer, "<|image_start|>", "<|image_end|>", "<|patch|>")
    # the vision MLP's width must equal the pixel-shuffled patch width: hidden / ratio² = 16 / 0.25 = 64
    config = Llama4Config(
        text_config=text,
        vision_config=dict(
            hidden_size=16,
            num_hidden_layers=1,
            num_attention_heads=2,
            intermediate_size=64,
            image_size=tile,
            patch_size=patch,
            pixel_shuffle_ratio=0.5,
            projector_input_dim=32,
            projector_output_dim=32,
            vision_output_dim=32,
            rope_parameters={"rope_type": "default", "rope_theta": 10000.0},
        ),
        boi_token_index=boi,
        eoi_token_index=eoi,
        image_token_index=image,
    )
    model = Llama4ForConditionalGeneration(config)
    image_processor = Llama4ImageProcessor(size={"height": tile, "width": tile}, max_patches=2)
    processor = Llama4Processor(
        image_processor=image_processor,
        tokenizer=tokenizer,
        patch_size=patch,
        pixel_shuffle_ratio=0.5,
        chat_template=LLAMA4_TEMPLATE,
    )
    _save(model, processor, path)


def _save(model, processor, path: Path) -> None:
    model.generation_config.eos_token_id = model.config.get_text_config().eos_token_id
    model.generation_config.pad_token_id = model.config.get_text_config().pad_token_id
    model.save_pretrained(path)
    processor.save_pretrained(path)


BUILDERS: dict[str, Callable[[Path, dict[str, int]], None]] = {
    "qwen2_vl": _qwen_saver(_build_qwen2_vl, "qwen2_vl"),
    "qwen2_5_vl": _qwen_saver(_build_qwen2_5_vl, "qwen2_5_vl"),
    "qwen3_vl": _qwen_saver(_build_qwen3_vl, "qwen3_vl"),
    "mllama": _save_mllama,
    "llama4": _save_llama4,
}
FAMILIES = tuple(BUILDERS)


def build_tiny_model(family: str, path: str | Path, *, seed: int = 0, hidden_size: int = 32, heads: int = 4) -> Path:
    """Write a tiny random-weight checkpoint of ``family`` (one of :data:`FAMILIES`) to ``path``.

    ``hidden_size`` and ``heads`` size the language model (vLLM's attention kernels want a head
    dimension of at least 32, e.g. ``hidden_size=128, heads=2``); the vision tower stays tiny.
    """
    import torch

    path = Path(path)
    torch.manual_seed(seed)
    BUILDERS[family](path, {"hidden_size": hidden_size, "heads": heads})
    return path


def teach_to_answer(
    path: str | Path,
    answer: str = "Keep the lane.",
    *,
    prompts: list[str],
    image: str,
    steps: int = 50,
    lr: float = 6e-3,
    seed: int = 0,
) -> Path:
    """Train the checkpoint at ``path`` (in place) to answer each of ``prompts`` with ``answer`` and its end token.

    Teacher forcing on [image, prompt] user turns through the model's own processor and chat template; the loss
    covers the answer tokens only. Fifty Adam steps make a tiny model end its answers (seconds on a CPU).
    """
    import torch
    from PIL import Image
    from transformers import AutoModelForImageTextToText, AutoProcessor

    torch.manual_seed(seed)
    path = Path(path)
    processor = AutoProcessor.from_pretrained(path)
    model = AutoModelForImageTextToText.from_pretrained(path, dtype=torch.float32)
    end = model.generation_config.eos_token_id
    end_token = processor.tokenizer.convert_ids_to_tokens(end[0] if isinstance(end, list) else end)
    picture = [[Image.open(image).convert("RGB")]]
    examples = []
    for prompt in prompts:
        turn = [{"role": "user", "content": [{"type": "image"}, {"type": "text", "text": prompt}]}]
        chat = processor.apply_chat_template(turn, add_generation_prompt=True, tokenize=False)
        n_prompt = processor(text=[chat], images=picture, return_tensors="pt")["input_ids"].shape[1]
        inputs = dict(processor(text=[chat + answer + end_token], images=picture, return_tensors="pt"))
        labels = inputs["input_ids"].clone()
        labels[:, :n_prompt] = -100
        examples.append((inputs, labels))
    optimizer = torch.optim.Adam(model.parameters(), lr=lr)
    model.train()
    for step in range(steps):
        inputs, labels = examples[step % len(examples)]
        loss = model(**inputs, labels=labels).loss
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    model.eval()
    model.save_pretrained(path)
    return path
