"""Input ablations: what of the frame a model is shown (``lightemma run --inputs``; docs/run.md#input-ablations).

* ``full`` — the paper's: the CAM_FRONT image in every stage and the history numbers in stages 2 and 3;
* ``no-image`` — the same three prompts, no image in any stage;
* ``blank-image`` — a uniform grey image (RGB 128, 128, 128) of the frame's image size in place of the
  camera image: the same image tokens, no information;
* ``no-history`` — the image, and the prompt set's ``no-history`` variant: its templates without the
  history numbers and the sentence that introduces them (:mod:`lightemma.prompts`).

Perturbations (docs/definitions.md#input-ablations), each seeded per frame from its sample token:

* ``corrupt:NAME@SEVERITY`` — the camera image corrupted (:mod:`lightemma.corruptions`, severity 1–5);
* ``history-noise@SV`` / ``history-noise@SV,SK`` — Gaussian noise of standard deviation SV m/s on the
  printed history speeds and SK 1/m on the printed curvatures (SK 0 when not given);
* ``history-stale@K`` — the printed history delayed by K steps of 0.5 s (K 1–5): pair j shows action
  max(1, j − K), the K oldest held at the oldest known action.

Only what the model is shown changes; the frame record keeps the true history, and scoring is the full run's.

The blank image is not a file: a request carries the reference ``blank-image:WxH`` where an image path
goes, and every backend's image reader (:func:`read_image_bytes` for the API, :func:`open_image` for
``hf`` / ``vllm``, in Ray replicas too) makes the image itself, so it needs no shared storage. It is
encoded as a baseline JPEG, which a uniform mid-grey survives exactly (every DCT coefficient is 0).
"""

from __future__ import annotations

import functools
import hashlib
import io
import re
from typing import Any

import numpy as np

from lightemma.corruptions import corrupted_jpeg, corruption_reference, corruption_seed, describe, parse_corruption
from lightemma.errors import InputError
from lightemma.nuscenes.geometry import round_like_python

INPUTS: tuple[str, ...] = ("full", "no-image", "blank-image", "no-history")
# the parametrised perturbations, as the choices are named to a user
PERTURBATIONS: tuple[str, ...] = ("corrupt:NAME@SEVERITY", "history-noise@SIGMA[,SIGMA_K]", "history-stale@K")
BLANK_PREFIX = "blank-image:"
CORRUPT_PREFIX = "corrupt:"  # lightemma.corruptions.PREFIX
BLANK_RGB = (128, 128, 128)
_BLANK = re.compile(r"blank-image:(\d{1,5})x(\d{1,5})")
_NUMBER = r"(?:\d+(?:\.\d*)?|\.\d+)"
_NOISE = re.compile(rf"history-noise@({_NUMBER})(?:,({_NUMBER}))?")
_STALE = re.compile(r"history-stale@(\S+)")
MAX_SPEED_SIGMA = 50.0  # m/s
MAX_CURVATURE_SIGMA = 1.0  # 1/m


def check_inputs(inputs: str) -> str:
    """``inputs`` when it is one of :data:`INPUTS` or a well-formed perturbation; one-line ValueError otherwise."""
    if not isinstance(inputs, str):
        raise InputError(f"inputs must be a string, got {type(inputs).__name__}")
    if inputs in INPUTS:
        return inputs

    if parse_corruption(inputs) is None and history_noise(inputs) is None and history_stale(inputs) is None:
        raise InputError(f"inputs must be one of {', '.join(INPUTS + PERTURBATIONS)}, got {inputs!r}")
    return inputs


def is_perturbation(inputs: str) -> bool:
    """True for a well-formed ``corrupt:…``, ``history-noise@…`` or ``history-stale@…``; False otherwise."""
    try:
        return inputs not in INPUTS and check_inputs(inputs) == inputs
    except ValueError:
        return False


def history_noise(inputs: str) -> tuple[float, float] | None:
    """(σ speed m/s, σ curvature 1/m) of ``history-noise@SV[,SK]``; None for other inputs; ValueError when malformed."""
    if not inputs.startswith("history-noise@"):
        return None
    match = _NOISE.fullmatch(inputs)
    if match is None:
        raise InputError(
            f"--inputs {inputs}: history noise is history-noise@SIGMA or history-noise@SIGMA,SIGMA_K "
            "(SIGMA m/s on speeds, SIGMA_K 1/m on curvatures, plain decimals)"
        )
    speed, curvature = float(match[1]), float(match[2] or 0.0)
    if not (speed <= MAX_SPEED_SIGMA and curvature <= MAX_CURVATURE_SIGMA) or speed == curvature == 0.0:
        raise InputError(
            f"--inputs {inputs}: needs 0 <= SIGMA <= {MAX_SPEED_SIGMA:g} m/s and 0 <= SIGMA_K <= "
            f"{MAX_CURVATURE_SIGMA:g} 1/m, not both 0"
        )
    return speed, curvature


def history_stale(inputs: str) -> int | None:
    """K of ``history-stale@K`` (1–5 steps of 0.5 s); None for other inputs; ValueError when malformed."""
    if not inputs.startswith("history-stale@"):
        return None
    match = _STALE.fullmatch(inputs)
    if match is None or not re.fullmatch(r"[1-5]", match[1]):
        raise InputError(f"--inputs {inputs}: K of history-stale@K must be an integer 1-5 (steps of 0.5 s)")
    return int(match[1])


def describe_perturbation(inputs: str) -> dict[str, Any]:
    """What the run manifest's ``params`` records of a perturbation: ``{"corruption": …}`` (transform, parameters,
    library, seed rule, encoding) or ``{"history_perturbation": …}``; ``{}`` for the other inputs."""
    corruption = parse_corruption(inputs)
    if corruption is not None:
        return {"corruption": describe(*corruption)}
    noise = history_noise(inputs)
    if noise is not None:
        seed = f"sha256('lightemma-history-noise|{inputs}|SAMPLE_TOKEN')[:8], big-endian"
        return {
            "history_perturbation": {
                "kind": "noise",
                "sigma_speed_m_s": noise[0],
                "sigma_curvature_per_m": noise[1],
                "seed": seed,
            }
        }
    k = history_stale(inputs)
    if k is not None:
        return {"history_perturbation": {"kind": "stale", "steps": k, "delay_s": 0.5 * k}}
    return {}


def perturbation_seed(kind: str, inputs: str, sample_token: str) -> int:
    """A frame's seed for ``inputs``: the first 8 bytes (big-endian) of SHA-256(``lightemma-KIND|INPUTS|TOKEN``)."""
    return int.from_bytes(hashlib.sha256(f"lightemma-{kind}|{inputs}|{sample_token}".encode()).digest()[:8], "big")


def shown_history(frame: Any, inputs: str) -> np.ndarray:
    """The (6, 2) history (speed m/s, curvature 1/m) the prompts print for ``frame`` under ``inputs``.

    The frame's own history except under ``history-noise`` (plus N(0, SV²) on each speed and N(0, SK²) on each
    curvature, drawn from :func:`perturbation_seed` of the frame's sample token: one standard-normal (6, 2)
    array of ``numpy.random.default_rng``; a perturbed column rounded to 3 decimals) and ``history-stale@K`` (pair j is the frame's pair max(1, j − K)).
    """
    actions = np.asarray(frame.history_actions, dtype=np.float64)
    noise = history_noise(inputs)
    if noise is not None:
        token = str(getattr(frame, "sample_token", None) or frame.frame_id)
        rng = np.random.default_rng(perturbation_seed("history-noise", inputs, token))

        noisy = actions + rng.standard_normal(actions.shape) * np.array(noise)
        # a perturbed column to 3 decimals (the paper's history precision), never 16 digits of noise in a prompt
        return np.where(np.array(noise) > 0, round_like_python(noisy), actions)
    k = history_stale(inputs)
    if k is not None:
        return actions[np.maximum(np.arange(len(actions)) - k, 0)]
    return actions


def blank_reference(width: int, height: int) -> str:
    """The image reference of a blank image of ``width`` × ``height`` pixels (``blank-image:WxH``)."""
    if not (0 < width < 100_000 and 0 < height < 100_000):
        raise InputError(f"a blank image needs a positive size below 100000 px, got {width}x{height}")
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
    if reference.startswith(CORRUPT_PREFIX):
        return corrupted_jpeg(reference)  # the one place a corruption is applied (every backend)
    with open(reference, "rb") as fh:
        return fh.read()


def open_image(reference: str) -> Any:
    """The image ``reference`` names as an RGB ``PIL.Image`` (a file, or a blank image). OSError / ValueError when unreadable."""
    from PIL import Image

    size = blank_size(reference)
    if size is not None:
        return Image.new("RGB", size, BLANK_RGB)
    if reference.startswith(CORRUPT_PREFIX):  # the API's bytes, decoded: every backend sees the same pixels
        with Image.open(io.BytesIO(read_image_bytes(reference))) as img:
            return img.convert("RGB")
    with Image.open(reference) as img:
        return img.convert("RGB")


def request_image(frame: Any, inputs: str) -> str | None:
    """What a request of ``frame`` carries as its image under ``inputs``: the frame's path, a blank or corruption
    reference (``corrupt:NAME@SEVERITY:SEED:PATH``, seeded from the frame's sample token), or None.

    ``blank-image`` reads the size from the image file's header; when the file cannot be read the
    reference names no size (``blank-image:unreadable``) and the call fails with an image-read error,
    exactly as a full run's call fails on that frame — the real image is never sent instead.
    """
    path = str(frame.image_path) if getattr(frame, "image_path", None) else None
    if inputs == "no-image" or path is None:
        return None
    if inputs.startswith(CORRUPT_PREFIX):
        name, severity = parse_corruption(inputs) or ("", 0)
        token = str(getattr(frame, "sample_token", None) or frame.frame_id)
        return corruption_reference(path, name, severity, corruption_seed(token, name, severity))
    if inputs != "blank-image":
        return path
    from PIL import Image

    try:
        with Image.open(path) as img:  # the header only
            width, height = img.size
    except (OSError, ValueError):
        return BLANK_PREFIX + "unreadable"
    return blank_reference(width, height)
