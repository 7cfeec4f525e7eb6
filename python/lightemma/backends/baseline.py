"""Baselines as backends: predictions that need no model and no API.

* ``constant`` — repeat the last history action (speed and curvature) six times;
* ``cv`` — constant speed (the last history speed), straight ahead (curvature 0);
* ``oracle`` — the ground-truth future actions; integrated, they show the
  integrator's own error floor (run it under ``euler`` and ``midpoint``);
* ``ego`` — a ridge regression from the history to the future actions, cross-fitted by scene on
  the evaluated frames or fitted on a training split (``fit_split``; :mod:`lightemma.backends.ego`).
  It is fitted before the run starts (:meth:`BaselineBackend.prepare`), and the fit (features,
  coefficients, folds, λ) is part of the backend's ``info`` in the manifest.

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

from lightemma.backends.base import Backend, ChatRequest, ChatResult
from lightemma.backends.ego import FOLDS, EgoFit
from lightemma.errors import InputError, ShapeError, UserError
from lightemma.frames import format_history
from lightemma.nuscenes import load_frames
from lightemma.nuscenes.geometry import round_like_python

KINDS: tuple[str, ...] = ("constant", "cv", "oracle", "ego")
STAGE_TEXTS = {
    "scene": "baseline: no scene description",
    "intent": "baseline: no driving intent",
}


def _field(frame: Any, name: str) -> np.ndarray:
    value = frame.get(name) if isinstance(frame, Mapping) else getattr(frame, name, None)
    if value is None:
        raise InputError(f"frame has no {name}")
    array = np.asarray(value, dtype=np.float64)
    if array.shape != (6, 2) or not np.isfinite(array).all():
        raise ShapeError(f"frame {name} must be 6 finite (speed, curvature) pairs, got shape {array.shape}")
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
    if kind == "ego":
        raise InputError(
            "baseline:ego predicts from a fit over the frame set (BaselineBackend.prepare), not from one frame"
        )
    raise InputError(f"unknown baseline {kind!r} (choose from {', '.join(KINDS)})")


def format_actions(actions: np.ndarray) -> str:
    """Six actions in the strict answer format ``[(v1, c1), (v2, c2), …]``, plain decimals of up to 6 places."""
    return format_history(round_like_python(actions, 6))


def format_actions_json(actions: np.ndarray) -> str:
    """Six actions as the structured answer ``{"actions": [[v1, c1], …]}``, plain decimals of up to 6 places."""
    import json

    return json.dumps({"actions": round_like_python(actions, 6).tolist()})


class BaselineBackend(Backend):
    """A :class:`lightemma.backends.base.Backend` answering from the frame itself."""

    def __init__(self, kind: str, *, fit_split: str | None = None, folds: int | None = None) -> None:
        if kind not in KINDS:
            raise InputError(f"unknown baseline {kind!r} (choose from {', '.join(KINDS)})")
        if kind != "ego" and (fit_split is not None or folds is not None):
            raise UserError(f"--fit-split is for baseline:ego; baseline:{kind} is not fitted")
        self.kind = kind
        self.name = f"baseline:{kind}"
        self.fit_split = fit_split
        self.folds = folds
        self._fit: Any = None  # the ego baseline's EgoFit, once prepared

    @property
    def info(self) -> Mapping[str, Any]:
        out = {
            "backend": "baseline",
            "kind": self.kind,
            "model": self.name,
            "gpus": None,
            "token_counting": "none (no model)",
        }
        if self._fit is not None:
            out["fit"] = self._fit.record
        return out

    def prepare(self, frames: Sequence[Any], dataset: Mapping[str, Any] | None = None) -> None:
        """Fit the ego baseline for ``frames`` before the run (nothing to do for the other baselines).

        With ``fit_split`` the training frames are loaded from the run's ``dataset`` (dataroot, version,
        window). Raises :class:`~lightemma.errors.UserError` when the fit cannot be made (too few scenes,
        a training split that shares scenes with the evaluated frames, frames passed in memory).
        """
        if self.kind != "ego":
            return

        folds = self.folds or FOLDS
        if self.fit_split is None:
            self._fit = EgoFit.cross_fit(frames, folds=folds)
            subset = _subset_taken(dataset or {}, len(frames))
            if subset:
                self._fit.record["subset"] = _subset_record(self._fit.record, subset)
            return

        dataset = dataset or {}
        if not dataset.get("dataroot") or not dataset.get("version"):
            raise UserError(
                "baseline:ego --fit-split needs a dataset (--dataroot, --version) to load the training split from"
            )

        train = load_frames(
            dataset["dataroot"],
            dataset["version"],
            split=self.fit_split,
            window=dataset.get("window") or "reference",
            on_missing_image="keep",
            on_bad_record=dataset.get("on_bad_record") or "skip",
        )
        self._fit = EgoFit.fit_split(train, frames, split=self.fit_split, folds=folds)

    def _answer(self, request: ChatRequest) -> ChatResult:
        if request.stage in STAGE_TEXTS:
            return ChatResult(
                text=STAGE_TEXTS[request.stage],
                input_tokens=0,
                output_tokens=0,
                cost_cents=0.0,
                finish_reason="stop",
                reasoning_tokens=0,
            )
        if request.stage != "actions":
            return ChatResult(text=None, error="ValueError", error_message=f"unknown stage {request.stage!r}")
        if request.frame is None:
            return ChatResult(
                text=None, error="ValueError", error_message=f"baseline needs the frame of {request.frame_id}"
            )
        try:
            actions = self._ego(request) if self.kind == "ego" else baseline_actions(self.kind, request.frame)
            text = format_actions(actions) if request.response_schema is None else format_actions_json(actions)
        except ValueError as exc:
            return ChatResult(text=None, error="ValueError", error_message=str(exc))
        return ChatResult(
            text=text, input_tokens=0, output_tokens=0, cost_cents=0.0, finish_reason="stop", reasoning_tokens=0
        )

    def _ego(self, request: ChatRequest) -> np.ndarray:
        if self._fit is None:
            raise ValueError("baseline:ego was not fitted (BaselineBackend.prepare) before it was asked")
        actions = self._fit.predictions.get(request.frame_id)
        if actions is None:
            raise ValueError(
                f"baseline:ego has no prediction for {request.frame_id} (not in the fitted frame set, "
                "or its history is not finite)"
            )
        return actions

    def structured_output(self) -> dict[str, Any]:
        """Baselines answer a response schema's JSON object themselves."""
        return {"mechanism": "the baseline writes the JSON object itself", "pair_count_enforced": True}

    async def generate(self, requests: Sequence[ChatRequest]) -> list[ChatResult]:
        """Answer every request, in order; a request it cannot answer gets an error result."""
        return [self._answer(r) for r in requests]

    async def aclose(self) -> None:
        """Nothing to release."""


def _subset_taken(dataset: Mapping[str, Any], n_frames: int) -> str | None:
    """The flag that cut the evaluated frames to a subset of the set (``--sample N`` / ``--limit N``), or None.

    ``--limit N`` that kept fewer than N frames took the whole set.
    """
    sample, limit = dataset.get("sample"), dataset.get("limit")
    if sample:
        return f"--sample {int(sample['n'])}"
    if limit is not None and n_frames >= int(limit):
        return f"--limit {int(limit)}"
    return None


def _subset_record(record: Mapping[str, Any], taken: str) -> dict[str, Any]:
    """The manifest's ``fit.subset`` of an ego baseline cross-fitted on a subset: what it fits on and the warning."""
    folds = list(record.get("folds") or [])
    per_fold = [int(f["fit_frames"]) for f in folds]
    frames = int(record.get("frames_predicted", 0)) + int(record.get("frames_without_prediction", 0))
    scenes = len({s for f in folds for s in f.get("predicted_scenes", [])})
    fits = (
        f"{min(per_fold)}–{max(per_fold)}"
        if per_fold and min(per_fold) != max(per_fold)
        else f"{per_fold[0] if per_fold else 0}"
    )
    warning = (
        f"warning: baseline:ego is cross-fitted on the {frames} frame(s) of {taken} only ({scenes} scenes; each fold's "
        f"fit sees {fits} frames): its ADE is worse than a fit on the full set and every model's gain over the best "
        "baseline is inflated; fit it with --fit-split train or run it on the full set"
    )
    return {"taken_by": taken, "frames": frames, "scenes": scenes, "fit_frames_per_fold": per_fold, "warning": warning}
