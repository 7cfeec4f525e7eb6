"""What the local backends (``hf``, ``vllm``) share: option checks, the chat turn, image loading, imports,
checkpoint facts.

Every stage of a frame is one user turn whose content is the image first, then
the stage's text (the paper's independent stages); in the ``conversation`` chain,
the earlier stages come first as user/assistant turns, and the image is in the
first user turn only. The image goes first in every backend so that the prompt
prefix (template header + image) is identical across the three requests of a
frame, which lets vLLM's prefix cache (and a provider's) reuse it; the layout is
the same for ``hf``, ``vllm`` and the API backend so all see the same prompt.
"""

from __future__ import annotations

import importlib
import json
import math
from pathlib import Path
from typing import Any

from lightemma.backends.base import ChatRequest
from lightemma.errors import UserError
from lightemma.inputs import open_image

# Llama-3.2-Vision (model_type "mllama") runs on hf only: current vLLM (0.32) does not support it.
MLLAMA_MODEL_TYPE = "mllama"


def require(module: str, extra: str) -> Any:
    """Import ``module`` or raise a :class:`UserError` naming the extra that provides it."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise UserError(
            f"the {extra} backend needs {module.split('.')[0]} ({exc}); install it with: "
            f"pip install 'lightemma[{extra}]'"
        ) from None


#: how both local backends decode (recorded in ``info``)
DECODING = (
    "greedy at temperature 0, else pure temperature sampling; the checkpoint's generation_config "
    "sampling settings (top-k/top-p, repetition penalty) are not used"
)


def check_options(batch_size: int, max_pixels: int | None) -> None:
    """The options both local backends take, checked with the CLI flag named."""
    if max_pixels is not None and max_pixels < 1:
        raise UserError(f"--max-pixels must be a positive number of pixels, got {max_pixels}")
    if batch_size < 1:
        raise UserError(f"--batch-size must be at least 1, got {batch_size}")


def conversation(request: ChatRequest, image_part: dict[str, Any] | None) -> list[dict[str, Any]]:
    """The messages of one request: its earlier turns (if any), then its user turn; ``image_part`` first in the first.

    Every content is a list of parts (``{"type": "text", "text": …}``), so that a backend can mark a part
    (Anthropic's cache breakpoints). A request without earlier turns is one user turn [image, text].
    """
    texts = [(role, text) for user, answer in request.turns for role, text in (("user", user), ("assistant", answer))]
    texts.append(("user", request.text))
    messages = []
    for i, (role, text) in enumerate(texts):
        content: list[dict[str, Any]] = [dict(image_part)] if i == 0 and image_part is not None else []
        content.append({"type": "text", "text": text})
        messages.append({"role": role, "content": content})
    return messages


def cap_pixels(width: int, height: int, max_pixels: int | None) -> tuple[int, int]:
    """(width, height) scaled down, aspect kept, so that width × height ≤ ``max_pixels`` (never up)."""
    if max_pixels is None or width * height <= max_pixels:
        return width, height
    scale = math.sqrt(max_pixels / (width * height))
    return max(1, math.floor(width * scale)), max(1, math.floor(height * scale))


def load_image(path: str, max_pixels: int | None = None) -> Any:
    """The image at ``path`` as an RGB ``PIL.Image``, downscaled to at most ``max_pixels`` pixels when given."""
    from PIL import Image

    try:
        image = open_image(path)  # a file, or a blank image (--inputs blank-image)
    except (OSError, ValueError) as exc:
        raise UserError(f"cannot read image {path}: {exc}") from None
    width, height = image.size
    size = cap_pixels(width, height, max_pixels)
    return image if size == image.size else image.resize(size, Image.Resampling.BICUBIC)


def checkpoint_config(model: str) -> dict[str, Any] | None:
    """The ``config.json`` of a local checkpoint directory, or None (hub ids are not fetched here)."""
    path = Path(model) / "config.json"
    if not path.is_file():
        return None
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError):
        return None
    return data if isinstance(data, dict) else None


def is_mllama(model: str, model_type: str | None = None) -> bool:
    """True for Llama-3.2-Vision: by ``model_type`` (or the checkpoint's config.json) or by the hub id."""
    if model_type is None:
        config = checkpoint_config(model)
        model_type = config.get("model_type") if config else None
    if model_type is not None:
        return model_type == MLLAMA_MODEL_TYPE
    name = model.lower()
    return "llama-3.2" in name and "vision" in name


def token_counting(model_type: str) -> str:
    """How input/output tokens are counted for a model of ``model_type`` (recorded in the manifest)."""
    if model_type == MLLAMA_MODEL_TYPE:
        image = (
            "one <|image|> token per image (the image itself enters through cross-attention and has no prompt tokens)"
        )
    else:
        image = "the image placeholder tokens the processor expands the image into (one per merged vision patch)"
    return (
        f"input: non-padding prompt token ids after the model's processor and chat template, including {image}; "
        "output: generated token ids up to and including the first end-of-turn token"
    )
