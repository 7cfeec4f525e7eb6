"""Parsing a model's stage-3 answer into (speed, curvature) actions (SPEC §3)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from lightemma import _core

STATUSES = ("ok", "corrected", "failed")
_STATUS_NAMES = np.array(STATUSES)


@dataclass(frozen=True)
class ParsedActions:
    """The parse of a batch of answers.

    Attributes:
        actions: float64 array (N, n, 2) of (speed m/s, curvature 1/m); NaN where failed.
        status: array of ``"ok"`` (strict format met), ``"corrected"`` (only the
            lenient parser found them) or ``"failed"``, one per answer.
        reason: why each answer was not ``"ok"`` (``""`` when it was).
    """

    actions: np.ndarray
    status: np.ndarray
    reason: list[str]

    def __len__(self) -> int:
        return len(self.reason)

    @property
    def ok(self) -> np.ndarray:
        """Boolean mask of answers whose actions are usable (``ok`` or ``corrected``)."""
        return self.status != "failed"


def parse_actions(texts: str | Sequence[str], *, n: int = 6, mode: str = "lenient") -> ParsedActions:
    """Parse model answers into ``n`` (speed, curvature) actions each.

    ``mode="strict"`` accepts only ``[(v1, c1), …, (vn, cn)]`` and nothing else;
    ``mode="lenient"`` (the default) also finds the first ``n`` bracketed pairs
    anywhere in the text, or failing that the first ``2n`` standalone numbers.
    The parser never raises for a bad answer: it reports ``"failed"`` with a reason.

    >>> import lightemma
    >>> p = lightemma.parse_actions("Actions: [(5.0, 0.0), (5.2, 0.01), (5.4, 0.01), (5.5, 0.0), (5.5, 0.0), (5.6, 0.0)]")
    >>> p.status[0], p.actions[0, 1].tolist()
    ('corrected', [5.2, 0.01])
    """
    if isinstance(texts, str):
        texts = [texts]
    elif not isinstance(texts, Sequence) or not all(isinstance(t, str) for t in texts):
        bad = next((i for i, t in enumerate(texts) if not isinstance(t, str)), None) if isinstance(texts, Sequence) else None
        where = f" (item {bad} is {type(texts[bad]).__name__})" if bad is not None else ""
        raise ValueError(f"texts must be a str or a sequence of str{where}")
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise ValueError(f"n must be a positive integer, got {n!r}")
    actions, codes, reasons = _core.parse_actions(list(texts), n, mode)
    return ParsedActions(actions=actions, status=_STATUS_NAMES[codes], reason=reasons)
