"""Image corruptions (``lightemma run --inputs corrupt:NAME@SEVERITY``; docs/definitions.md#input-ablations).

Each corruption is one albumentations 2.0 transform whose parameters are fixed per severity (1 mildest … 5
harshest; :data:`CORRUPTIONS`, the table in docs/definitions.md): no parameter is drawn from a range. What is
random (where the rain drops, the occluding patch or the noise fall, the blur's direction) is drawn from a
seed derived from the frame's sample token and the corruption (:func:`corruption_seed`), so a frame's
corrupted image is the same in every run and every backend.

A request carries the reference ``corrupt:NAME@SEVERITY:SEED:PATH`` where an image path goes
(:func:`corruption_reference`); every backend's image reader resolves it through :func:`corrupted_jpeg` —
the one place that applies a corruption: the API and batch backends send its bytes, ``hf`` / ``vllm`` and Ray
replicas decode the same bytes (:func:`lightemma.inputs.open_image`). The corrupted image is encoded as a
JPEG at quality :data:`JPEG_QUALITY` (PIL, 4:2:0), the image every backend is shown.

Frost (ImageNet-C blends one of six frost photographs that only its own package ships) is not among them.
"""

from __future__ import annotations

import functools
import hashlib
import io
import os
import re
from collections.abc import Callable
from typing import Any

import numpy as np

from lightemma.errors import InputError

SEVERITIES: tuple[int, ...] = (1, 2, 3, 4, 5)
PREFIX = "corrupt:"
JPEG_QUALITY = 95
_SPEC = re.compile(r"corrupt:([a-z0-9-]+)@(\S+)")
_REFERENCE = re.compile(r"corrupt:([a-z0-9-]+)@([1-5]):(\d{1,10}):(.+)", re.DOTALL)

# name → (albumentations transform, its keyword arguments at severities 1 … 5), pinned: docs/definitions.md
_NEAREST, _AREA = 0, 3  # cv2.INTER_NEAREST, cv2.INTER_AREA
CORRUPTIONS: dict[str, tuple[str, tuple[dict[str, Any], ...]]] = {
    "brightness": (
        "RandomBrightnessContrast",
        tuple({"brightness_limit": (b, b), "contrast_limit": (0.0, 0.0)} for b in (0.1, 0.2, 0.3, 0.4, 0.5)),
    ),
    "dark": ("RandomGamma", tuple({"gamma_limit": (g, g)} for g in (150, 200, 250, 300, 350))),
    # x·c + 255·(1 − c)/2: contrast scaled by ImageNet-C's factors c around mid-grey
    "contrast": (
        "RandomBrightnessContrast",
        tuple(
            {"brightness_limit": (round((1 - c) / 2, 4),) * 2, "contrast_limit": (round(c - 1, 4),) * 2}
            for c in (0.4, 0.3, 0.2, 0.1, 0.05)
        ),
    ),
    # homogeneous fog (atmospheric scattering): x·t + A·(1 − t), transmission t, airlight A = 0.9 × 255;
    # albumentations' RandomFog takes 2-5 s a 1600×900 frame (a full-image copy per fog particle)
    "fog": (
        "RandomBrightnessContrast",
        tuple(
            {"brightness_limit": (round(0.9 * (1 - t), 4),) * 2, "contrast_limit": (round(t - 1, 4),) * 2}
            for t in (0.8, 0.65, 0.5, 0.35, 0.2)
        ),
    ),
    "rain": (
        "RandomRain",
        tuple(
            {"rain_type": t, "brightness_coefficient": b, "slant_range": (-10.0, 10.0), "blur_value": 3}
            for t, b in (("drizzle", 0.9), ("default", 0.8), ("heavy", 0.75), ("torrential", 0.7), ("torrential", 0.6))
        ),
    ),
    "snow": (
        "RandomSnow",
        tuple(
            {"snow_point_range": (s, s), "brightness_coeff": 2.5, "method": "bleach"} for s in (0.1, 0.2, 0.3, 0.4, 0.5)
        ),
    ),
    "motion-blur": (
        "MotionBlur",
        tuple(
            {"blur_limit": (k, k), "angle_range": (0.0, 360.0), "direction_range": (-1.0, 1.0), "allow_shifted": False}
            for k in (7, 11, 15, 21, 31)
        ),
    ),
    "defocus-blur": (
        "Defocus",
        tuple({"radius": (r, r), "alias_blur": (a, a)} for r, a in ((3, 0.1), (4, 0.5), (6, 0.5), (8, 0.5), (10, 0.5))),
    ),
    "zoom-blur": (
        "ZoomBlur",
        tuple(
            {"max_factor": (m, m), "step_factor": (s, s)}
            for m, s in ((1.11, 0.01), (1.16, 0.01), (1.21, 0.02), (1.26, 0.02), (1.31, 0.03))
        ),
    ),
    "gaussian-noise": (
        "GaussNoise",
        tuple(
            {"std_range": (s, s), "mean_range": (0.0, 0.0), "per_channel": True} for s in (0.08, 0.12, 0.18, 0.26, 0.38)
        ),
    ),
    "jpeg": (
        "ImageCompression",
        tuple({"compression_type": "jpeg", "quality_range": (q, q)} for q in (25, 18, 15, 10, 7)),
    ),
    "pixelate": (
        "Downscale",
        tuple(
            {"scale_range": (s, s), "interpolation_pair": {"downscale": _AREA, "upscale": _NEAREST}}
            for s in (0.6, 0.5, 0.4, 0.3, 0.25)
        ),
    ),
    "occlusion": (
        "CoarseDropout",
        tuple(
            {"num_holes_range": (1, 1), "hole_height_range": (f, f), "hole_width_range": (f, f), "fill": 0}
            for f in (0.2, 0.3, 0.4, 0.5, 0.6)
        ),
    ),
}
NAMES: tuple[str, ...] = tuple(CORRUPTIONS)


def parse_corruption(inputs: str) -> tuple[str, int] | None:
    """(name, severity) of ``corrupt:NAME@SEVERITY``; None for any other ``inputs``.

    ValueError (one line, naming the corruption and the choices) for an unknown name or a severity that is not
    an integer 1–5.
    """
    if not inputs.startswith(PREFIX):
        return None
    match = _SPEC.fullmatch(inputs)
    if match is None:
        raise InputError(
            f"--inputs {inputs}: a corruption is corrupt:NAME@SEVERITY (severity 1-5), NAME one of {', '.join(NAMES)}"
        )
    name, severity = match[1], match[2]
    if name not in CORRUPTIONS:
        raise InputError(f"--inputs {inputs}: unknown corruption {name!r}; one of {', '.join(NAMES)}")
    if not re.fullmatch(r"[1-5]", severity):
        raise InputError(f"--inputs {inputs}: severity must be an integer 1-5, got {severity!r}")
    return name, int(severity)


def corruption_seed(sample_token: str, name: str, severity: int) -> int:
    """The seed of a frame's corruption: the first 4 bytes (big-endian) of
    SHA-256(``lightemma-corrupt|NAME@SEVERITY|SAMPLE_TOKEN``), an integer in [0, 2³²)."""
    digest = hashlib.sha256(f"lightemma-corrupt|{name}@{severity}|{sample_token}".encode()).digest()
    return int.from_bytes(digest[:4], "big")


def corruption_reference(path: str, name: str, severity: int, seed: int) -> str:
    """The image reference of ``path`` corrupted by ``name`` at ``severity`` with ``seed``."""
    if name not in CORRUPTIONS or severity not in SEVERITIES or not 0 <= seed < 2**32:
        raise InputError(f"no corruption {name}@{severity} with seed {seed}")
    return f"{PREFIX}{name}@{severity}:{seed}:{path}"


def parse_reference(reference: str) -> tuple[str, int, int, str] | None:
    """(name, severity, seed, path) of a corruption reference; None for any other reference. OSError when malformed."""
    if not reference.startswith(PREFIX):
        return None
    match = _REFERENCE.fullmatch(reference)
    if match is None or match[1] not in CORRUPTIONS or int(match[3]) >= 2**32:
        raise OSError(f"malformed corruption reference {reference[:120]!r} (expected corrupt:NAME@SEVERITY:SEED:PATH)")
    return match[1], int(match[2]), int(match[3]), match[4]


@functools.lru_cache(maxsize=1)
def _albumentations() -> Any:
    os.environ.setdefault("NO_ALBUMENTATIONS_UPDATE", "1")  # no version check over the network at import
    import albumentations

    return albumentations


def transform(name: str, severity: int) -> Callable[..., dict[str, Any]]:
    """The albumentations transform of ``name`` at ``severity`` (p = 1: always applied)."""
    cls, table = CORRUPTIONS[name]
    return getattr(_albumentations(), cls)(p=1.0, **table[severity - 1])


def corrupt_array(rgb: np.ndarray, name: str, severity: int, seed: int) -> np.ndarray:
    """``rgb`` (H, W, 3) uint8 corrupted by ``name`` at ``severity``, its random draws from ``seed``: (H, W, 3) uint8.

    The same (image, name, severity, seed) gives the same array in every process.
    """
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
        raise InputError(f"a corruption needs an (H, W, 3) uint8 image, got {rgb.shape} {rgb.dtype}")
    compose = _albumentations().Compose([transform(name, severity)], seed=seed, strict=True)
    out = compose(image=np.ascontiguousarray(rgb))["image"]
    return np.ascontiguousarray(out, dtype=np.uint8)


def encode_jpeg(rgb: np.ndarray) -> bytes:
    """``rgb`` (H, W, 3) uint8 as the JPEG every backend is shown (PIL, quality :data:`JPEG_QUALITY`)."""
    from PIL import Image

    out = io.BytesIO()
    Image.fromarray(rgb, "RGB").save(out, format="JPEG", quality=JPEG_QUALITY)
    return out.getvalue()


@functools.lru_cache(maxsize=64)  # a local backend's batch reads each frame's image once per stage
def corrupted_jpeg(reference: str) -> bytes:
    """The JPEG bytes of a corruption reference: the file decoded to RGB, corrupted, encoded.

    OSError when the reference is malformed or the file cannot be read or decoded (the call fails with an
    image-read error, as a full run's call on that frame would; the clean image is never sent instead).
    """
    from PIL import Image

    parsed = parse_reference(reference)
    if parsed is None:
        raise OSError(f"not a corruption reference: {reference[:120]!r}")
    name, severity, seed, path = parsed
    try:
        with Image.open(path) as img:
            rgb = np.asarray(img.convert("RGB"))
    except (OSError, ValueError) as exc:
        raise OSError(f"cannot read image {path}: {exc}") from None
    return encode_jpeg(corrupt_array(rgb, name, severity, seed))


def describe(name: str, severity: int) -> dict[str, Any]:
    """The corruption as the run manifest records it: name, severity, transform and its parameters, library,
    seed rule and encoding."""
    cls, table = CORRUPTIONS[name]
    params = {k: list(v) if isinstance(v, tuple) else v for k, v in table[severity - 1].items()}
    return {
        "name": name,
        "severity": severity,
        "transform": f"albumentations.{cls}",
        "params": params,
        "library": f"albumentations {_albumentations().__version__}",
        "seed": "sha256('lightemma-corrupt|NAME@SEVERITY|SAMPLE_TOKEN')[:4], big-endian",
        "encoding": f"JPEG quality {JPEG_QUALITY} (PIL)",
    }
