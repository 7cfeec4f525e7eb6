"""Input ablations: what of the frame a model is shown (``lightemma run --inputs``; docs/run.md#input-ablations).

* ``full`` — the paper's: the CAM_FRONT image in every stage and the history numbers in stages 2 and 3;
* ``no-image`` — the same three prompts, no image in any stage;
* ``blank-image`` — a uniform grey image (RGB 128, 128, 128) of the frame's image size in place of the
  camera image: the same image tokens, no information;
* ``no-history`` — the image, and the prompt set's ``no-history`` variant: its templates without the
  history numbers and the sentence that introduces them (:mod:`lightemma.prompts`).

The blank image is not a file: a request carries the reference ``blank-image:WxH`` where an image path
goes, and every backend's image reader (:func:`read_image_bytes` for the API, :func:`open_image` for
``hf`` / ``vllm``, in Ray replicas too) makes the image itself, so it needs no shared storage. It is
encoded as a baseline JPEG, which a uniform mid-grey survives exactly (every DCT coefficient is 0).
"""

from __future__ import annotations

import functools
import io
import re
from typing import Any

INPUTS: tuple[str, ...] = ("full", "no-image", "blank-image", "no-history")
BLANK_PREFIX = "blank-image:"
BLANK_RGB = (128, 128, 128)
_BLANK = re.compile(r"blank-image:(\d{1,5})x(\d{1,5})")


def check_inputs(inputs: str) -> str:
    """``inputs`` when it is one of :data:`INPUTS`; ValueError naming the choices otherwise."""
    if inputs not in INPUTS:
        raise ValueError(f"inputs must be one of {', '.join(INPUTS)}, got {inputs!r}")
    return inputs


def blank_reference(width: int, height: int) -> str:
    """The image reference of a blank image of ``width`` × ``height`` pixels (``blank-image:WxH``)."""
    if not (0 < width < 100_000 and 0 < height < 100_000):
        raise ValueError(f"a blank image needs a positive size below 100000 px, got {width}x{height}")
    return f"{BLANK_PREFIX}{int(width)}x{int(height)}"


def blank_size(reference: str) -> tuple[int, int] | None:
    """(width, height) of a blank-image reference; None for an ordinary path. OSError for a malformed one."""
    if not reference.startswith(BLANK_PREFIX):
        return None
    match = _BLANK.fullmatch(reference)
    if match is None or 0 in (int(match[1]), int(match[2])):
        raise OSError(f"malformed blank-image reference {reference!r} (expected blank-image:WIDTHxHEIGHT)")
    return int(match[1]), int(match[2])


@functools.lru_cache(maxsize=8)
def blank_jpeg(width: int, height: int) -> bytes:
    """A uniform grey (:data:`BLANK_RGB`) JPEG of ``width`` × ``height`` (decodes to exactly that grey)."""
    from PIL import Image

    out = io.BytesIO()
    Image.new("RGB", (width, height), BLANK_RGB).save(out, format="JPEG", quality=95)
    return out.getvalue()


def read_image_bytes(reference: str) -> bytes:
    """The bytes of the image ``reference`` names: a file's contents, or a blank image's JPEG. OSError when unreadable."""
    size = blank_size(reference)
    if size is not None:
        return blank_jpeg(*size)
    with open(reference, "rb") as fh:
        return fh.read()


def open_image(reference: str) -> Any:
    """The image ``reference`` names as an RGB ``PIL.Image`` (a file, or a blank image). OSError / ValueError when unreadable."""
    from PIL import Image

    size = blank_size(reference)
    if size is not None:
        return Image.new("RGB", size, BLANK_RGB)
    with Image.open(reference) as img:
        return img.convert("RGB")


def request_image(frame: Any, inputs: str) -> str | None:
    """What a request of ``frame`` carries as its image under ``inputs``: the frame's path, a blank reference, or None.

    ``blank-image`` reads the size from the image file's header; when the file cannot be read the
    reference names no size (``blank-image:unreadable``) and the call fails with an image-read error,
    exactly as a full run's call fails on that frame — the real image is never sent instead.
    """
    path = str(frame.image_path) if getattr(frame, "image_path", None) else None
    if inputs == "no-image" or path is None:
        return None
    if inputs != "blank-image":
        return path
    from PIL import Image

    try:
        with Image.open(path) as img:  # the header only
            width, height = img.size
    except (OSError, ValueError):
        return BLANK_PREFIX + "unreadable"
    return blank_reference(width, height)
