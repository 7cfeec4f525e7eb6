"""Baselines as backends: predictions that need no model and no API.

* ``constant`` — repeat the last history action (speed and curvature) six times;
* ``cv`` — constant speed (the last history speed), straight ahead (curvature 0);
* ``oracle`` — the ground-truth future actions; integrated, they show the
  integrator's own error floor (run it under ``euler`` and ``midpoint``).

They run through the same three-stage chain, parser, accounting and run store
as any model (``lightemma run --model baseline:cv``), so their runs have exactly
the format of model runs: stages 1 and 2 get a fixed short text, stage 3 the
six actions in the strict format ``[(v1, c1), …]`` (or, asked for a response
schema, the JSON object ``{"actions": [[v1, c1], …]}``); zero tokens, zero cost.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from lightemma.backends.base import ChatRequest, ChatResult
from lightemma.frames import format_history
from lightemma.frames.geometry import round_like_python

KINDS: tuple[str, ...] = ("constant", "cv", "oracle")
STAGE_TEXTS = {
    "scene": "baseline: no scene description",
    "intent": "baseline: no driving intent",
}


def _field(frame: Any, name: str) -> np.ndarray:
    value = frame.get(name) if isinstance(frame, Mapping) else getattr(frame, name, None)
    if value is None:
        raise ValueError(f"frame has no {name}")
    array = np.asarray(value, dtype=np.float64)
    if array.shape != (6, 2) or not np.isfinite(array).all():
        raise ValueError(f"frame {name} must be 6 finite (speed, curvature) pairs, got shape {array.shape}")
    return array


def baseline_actions(kind: str, frame: Any) -> np.ndarray:
    """The (6, 2) actions a baseline predicts for ``frame`` (history_actions / gt_actions)."""
    if kind == "constant":
        return np.repeat(_field(frame, "history_actions")[-1:], 6, axis=0)
    if kind == "cv":
        speed = _field(frame, "history_actions")[-1, 0]
        return np.array([[speed, 0.0]] * 6)
    if kind == "oracle":
        return _field(frame, "gt_actions").copy()
    raise ValueError(f"unknown baseline {kind!r} (choose from {', '.join(KINDS)})")


def format_actions(actions: np.ndarray) -> str:
    """Six actions in the strict answer format ``[(v1, c1), (v2, c2), …]``, plain decimals of up to 6 places."""
    return format_history(round_like_python(actions, 6))


def format_actions_json(actions: np.ndarray) -> str:
    """Six actions as the structured answer ``{"actions": [[v1, c1], …]}``, plain decimals of up to 6 places."""
    import json

    return json.dumps({"actions": round_like_python(actions, 6).tolist()})


class BaselineBackend:
    """A :class:`lightemma.backends.base.Backend` answering from the frame itself."""

    def __init__(self, kind: str) -> None:
        if kind not in KINDS:
            raise ValueError(f"unknown baseline {kind!r} (choose from {', '.join(KINDS)})")
        self.kind = kind
        self.name = f"baseline:{kind}"

    @property
    def info(self) -> Mapping[str, Any]:
        return {"backend": "baseline", "kind": self.kind, "model": self.name, "gpus": None, "token_counting": "none (no model)"}

    def _answer(self, request: ChatRequest) -> ChatResult:
        if request.stage in STAGE_TEXTS:
            return ChatResult(text=STAGE_TEXTS[request.stage], input_tokens=0, output_tokens=0, cost_cents=0.0,
                              finish_reason="stop", reasoning_tokens=0)
        if request.stage != "actions":
            return ChatResult(text=None, error="ValueError", error_message=f"unknown stage {request.stage!r}")
        if request.frame is None:
            return ChatResult(text=None, error="ValueError", error_message=f"baseline needs the frame of {request.frame_id}")
        try:
            actions = baseline_actions(self.kind, request.frame)
            text = format_actions(actions) if request.response_schema is None else format_actions_json(actions)
        except ValueError as exc:
            return ChatResult(text=None, error="ValueError", error_message=str(exc))
        return ChatResult(text=text, input_tokens=0, output_tokens=0, cost_cents=0.0, finish_reason="stop", reasoning_tokens=0)

    def structured_output(self) -> dict[str, Any]:
        """Baselines answer a response schema's JSON object themselves."""
        return {"mechanism": "the baseline writes the JSON object itself", "pair_count_enforced": True}

    async def generate(self, requests: Sequence[ChatRequest]) -> list[ChatResult]:
        """Answer every request, in order; a request it cannot answer gets an error result."""
        return [self._answer(r) for r in requests]

    async def aclose(self) -> None:
        """Nothing to release."""
