"""Plain-decimal rendering of history actions for prompts (SPEC §1).

Numbers are written as plain decimals (``4.512``), never as a library repr
such as ``np.float64(4.512)`` and never in exponent notation; ``-0.0`` is
written ``0.0``.
"""

from __future__ import annotations

import math
from decimal import Decimal
from collections.abc import Sequence

import numpy as np


def format_number(x: float) -> str:
    """Shortest plain decimal that round-trips ``x``: ``4.512``, ``0.0``, ``12.0``, ``0.00001``.

    ``-0.0`` becomes ``0.0``; NaN and infinities raise ``ValueError`` (they have
    no place in a prompt).
    """
    try:
        value = float(x)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"cannot render {x!r} as a number") from exc
    if not math.isfinite(value):
        raise ValueError(f"cannot render non-finite number {value!r} in a prompt")
    if value == 0.0:
        return "0.0"
    text = repr(value)
    if "e" in text or "E" in text:
        # exponent notation: expand repr's shortest round-tripping digits exactly
        text = format(Decimal(text), "f")
        if "." not in text:
            text += ".0"
    return text


def format_history(actions: np.ndarray | Sequence[Sequence[float]]) -> str:
    """Render (speed, curvature) actions as ``[(4.512, 0.0), (4.6, -0.012), ...]``.

    ``actions`` has shape ``(T, 2)``; the order is kept (most recent last).
    """
    arr = np.asarray(actions, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise ValueError(f"history actions must have shape (T, 2), got {arr.shape}")
    pairs = (f"({format_number(v)}, {format_number(c)})" for v, c in arr.tolist())
    return "[" + ", ".join(pairs) + "]"
