"""The ego-status baseline (``baseline:ego``): the future actions as a ridge regression on the history alone.

AD-MLP in spirit ("Rethinking the Open-Loop Evaluation of End-to-End Autonomous Driving in nuScenes",
Zhai et al. 2023; "Is Ego Status All You Need for Open-Loop End-to-End Autonomous Driving?", Li et al.
2024): whatever a model gains over this baseline, it did not get from the frame's history. Definitions:
docs/definitions.md#the-ego-status-baseline.

* **Features** (23 per frame, :data:`FEATURES`): the six history actions (v₁…v₆ in m/s, κ₁…κ₆ in 1/m,
  oldest first), the five accelerations they imply, aₖ = (vₖ₊₁ − vₖ) / 0.5 s (m/s²), and the six yaw
  rates ωₖ = vₖ·κₖ (rad/s).
* **Targets** (12): the six future actions (``gt_actions``: v, κ of steps 1…6).
* **Model**: features standardised (mean 0, variance 1 on the fitting frames; a constant feature keeps
  scale 1), then ridge regression with an intercept (scikit-learn ``StandardScaler`` + ``Ridge``), one λ
  for all targets. λ is chosen from :data:`LAMBDAS` by cross-validation over scene folds
  (``GroupKFold``), minimising the mean squared error of the targets standardised on the fitting frames
  (so speed and curvature weigh alike; the fit for a given λ does not depend on that scaling).
* **Fitting**: on a training split when one is given (``fit_split``: every evaluated frame predicted by one
  fit, λ by ``folds``-fold scene CV on the training frames), otherwise **cross-fitted by scene** on the
  evaluated frames: ``folds`` scene folds (``GroupKFold``, deterministic), each fold's frames predicted by a
  fit on the other folds, its λ chosen by an inner scene CV on those other folds only (nested CV) — no
  frame is ever predicted by a fit that saw its own scene, its targets or its scene's targets. Cross-fitted
  on a ``--sample`` / ``--limit`` subset, each fold fits on that subset's other folds only (a few frames):
  the run warns in one line and records it as ``fit.subset`` (:meth:`BaselineBackend.prepare`).

* **Small fits**: a fit on fewer than :data:`MIN_FIT_SCENES` scenes or :data:`MIN_FIT_FRAMES` frames (10 per feature)
  has seen few kinds of driving and extrapolates to the others (``lightemma demo``'s few synthetic scenes, one per
  kind of driving, are such a set). The record then holds ``warning`` (one line: the smallest fit's scenes and
  frames), which the run prints; the baseline's ADE then overstates its error, and every gain over it.

Everything is deterministic: the same frames give the same folds, λ and predictions.
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterator, Sequence
from typing import Any, Protocol

import numpy as np

from lightemma.definitions import STEP_SECONDS
from lightemma.errors import ShapeError, UserError

FOLDS = 5  # scene folds of the cross-fit (and of λ's cross-validation)
LAMBDAS: tuple[float, ...] = tuple(float(x) for x in np.logspace(-3, 3, 13))
FEATURES: tuple[str, ...] = (
    *(f"v{k}" for k in range(1, 7)),
    *(f"kappa{k}" for k in range(1, 7)),
    *(f"a{k}" for k in range(1, 6)),
    *(f"yaw_rate{k}" for k in range(1, 7)),
)
TARGETS: tuple[str, ...] = tuple(f"{name}{k}" for k in range(1, 7) for name in ("v", "kappa"))  # gt_actions row-major
MIN_FIT_SCENES = 20  # a fit on fewer scenes has seen few kinds of driving: the run warns (see the module docstring)
MIN_FIT_FRAMES = 10 * len(FEATURES)  # 230: ten frames per feature, or the run warns


def small_fit_warning(fits: Sequence[tuple[int, int]], where: str) -> str | None:
    """One warning line when the smallest of ``fits`` ((scenes, frames) of each fit, e.g. each cross-fit fold's) has
    fewer than :data:`MIN_FIT_SCENES` scenes or :data:`MIN_FIT_FRAMES` frames; None when every fit is large enough.
    ``where`` says what the fits are (``each fold's fit``, ``the fit on 'train'``)."""
    if not fits:
        return None
    scenes, frames = min(s for s, _ in fits), min(f for _, f in fits)
    if scenes >= MIN_FIT_SCENES and frames >= MIN_FIT_FRAMES:
        return None
    return (
        f"warning: baseline:ego is fitted on few frames: {where} sees as few as {scenes} scene(s) and "
        f"{frames} frame(s) (fewer than {MIN_FIT_SCENES} scenes or {MIN_FIT_FRAMES} frames); it extrapolates to "
        "kinds of driving it has not seen, so its ADE overstates the baseline's error and every model's gain over "
        "it; fit it on more scenes (--fit-split train, or run it on a larger set)"
    )


def ego_features(history: np.ndarray) -> np.ndarray:
    """(N, 23) features of :data:`FEATURES` from history actions (N, 6, 2) (speed m/s, curvature 1/m)."""
    h = np.asarray(history, dtype=np.float64)
    if h.ndim != 3 or h.shape[1:] != (6, 2):
        raise ShapeError(f"history actions must be (N, 6, 2), got {h.shape}")
    v, kappa = h[:, :, 0], h[:, :, 1]
    return np.concatenate([v, kappa, np.diff(v, axis=1) / STEP_SECONDS, v * kappa], axis=1)


def _field(frame: Any, name: str) -> np.ndarray:
    value = frame.get(name) if isinstance(frame, dict) else getattr(frame, name, None)
    return np.full((6, 2), np.nan) if value is None else np.asarray(value, dtype=np.float64).reshape(6, 2)


class Frames(Protocol):
    """Frames as the fit reads them: a list of frames or records, or a :class:`lightemma.frames.FrameSet`."""

    def __len__(self) -> int: ...

    def __iter__(self) -> Iterator[Any]: ...


def _arrays(frames: Frames) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[str]]:
    """(features (N, 23), targets (N, 12), scene names (N,), frame ids) of ``frames``."""
    history = np.stack([_field(f, "history_actions") for f in frames]) if len(frames) else np.zeros((0, 6, 2))
    future = np.stack([_field(f, "gt_actions") for f in frames]) if len(frames) else np.zeros((0, 6, 2))
    scenes = np.asarray(
        [str(getattr(f, "scene_name", None) if not isinstance(f, dict) else f.get("scene_name")) for f in frames],
        dtype=object,
    )
    ids = [str(getattr(f, "frame_id", None) if not isinstance(f, dict) else f.get("frame_id")) for f in frames]
    return ego_features(history), future.reshape(len(frames), 12), scenes, ids


class _Fit:
    """One fitted ridge model: λ chosen by scene CV on its fitting frames, then refitted on all of them."""

    def __init__(self, X: np.ndarray, Y: np.ndarray, scenes: np.ndarray, folds: int, lambdas: Sequence[float]) -> None:
        from sklearn.linear_model import Ridge
        from sklearn.model_selection import GridSearchCV, GroupKFold
        from sklearn.pipeline import Pipeline
        from sklearn.preprocessing import StandardScaler

        n_scenes = len(np.unique(scenes))
        if n_scenes < 2:
            raise UserError(
                f"baseline:ego needs at least 2 scenes to choose λ by scene cross-validation; its fit has {n_scenes}"
            )
        self.y_mean = Y.mean(axis=0)
        self.y_scale = Y.std(axis=0)
        self.y_scale[self.y_scale == 0] = 1.0
        search = GridSearchCV(
            Pipeline([("scale", StandardScaler()), ("ridge", Ridge())]),
            {"ridge__alpha": list(lambdas)},
            cv=GroupKFold(n_splits=min(folds, n_scenes)),
            scoring="neg_mean_squared_error",
            refit=True,
        )
        search.fit(X, (Y - self.y_mean) / self.y_scale, groups=scenes)
        self.model = search.best_estimator_
        self.lam = float(search.best_params_["ridge__alpha"])
        self.cv_mse = {f"{a:g}": float(-s) for a, s in zip(lambdas, search.cv_results_["mean_test_score"])}
        self.inner_folds = min(folds, n_scenes)
        self.frames = len(X)
        self.scenes = sorted(str(s) for s in np.unique(scenes))

    def predict(self, X: np.ndarray) -> np.ndarray:
        """(N, 12) predicted targets (original units)."""
        return self.model.predict(X) * self.y_scale + self.y_mean

    def linear_map(self) -> tuple[np.ndarray, np.ndarray]:
        """(coefficients (12, 23), intercepts (12,)) in original units: target = intercept + coefficients · features."""
        scaler, ridge = self.model.named_steps["scale"], self.model.named_steps["ridge"]
        coef = ridge.coef_ / scaler.scale_[None, :]  # per raw feature, in standardised-target units
        intercept = ridge.intercept_ - coef @ scaler.mean_
        return coef * self.y_scale[:, None], intercept * self.y_scale + self.y_mean

    def record(self) -> dict[str, Any]:
        coef, intercept = self.linear_map()
        return {
            "lambda": self.lam,
            "cv_folds": self.inner_folds,
            "cv_mse_standardised": self.cv_mse,
            "fit_frames": self.frames,
            "fit_scenes": len(self.scenes),
            "coefficients": coef.tolist(),
            "intercepts": intercept.tolist(),
        }


def _usable(X: np.ndarray, Y: np.ndarray | None = None) -> np.ndarray:
    ok = np.isfinite(X).all(axis=1)
    return ok if Y is None else ok & np.isfinite(Y).all(axis=1)


class EgoFit:
    """The ego baseline's predictions for a frame set and the record of how they were made (for the manifest).

    ``predictions``: frame id -> (6, 2) actions; frames whose history is not finite have none.
    """

    def __init__(self, predictions: dict[str, np.ndarray], record: dict[str, Any]) -> None:
        self.predictions = predictions
        self.record = record

    @staticmethod
    def fingerprint(predictions: dict[str, np.ndarray]) -> str:
        """``sha256:<hex>`` of the predictions (frame ids in order, values rounded to the 6 places sent)."""
        h = hashlib.sha256()
        for fid in sorted(predictions):
            h.update(fid.encode("utf-8"))
            h.update(np.round(predictions[fid], 6).astype("<f8").tobytes())
        return "sha256:" + h.hexdigest()

    @classmethod
    def _make(cls, ids: list[str], X: np.ndarray, pred: np.ndarray, record: dict[str, Any]) -> EgoFit:
        ok = _usable(X)
        predictions = {fid: pred[i].reshape(6, 2) for i, fid in enumerate(ids) if ok[i]}
        record = {
            "method": record.pop("method"),
            "features": list(FEATURES),
            "targets": list(TARGETS),
            "model": "StandardScaler + Ridge (scikit-learn), one λ for all targets, intercept",
            "lambdas": list(LAMBDAS),
            **record,
            "frames_predicted": len(predictions),
            "frames_without_prediction": len(ids) - len(predictions),
        }
        record["predictions_sha256"] = cls.fingerprint(predictions)
        return cls(predictions, record)

    @classmethod
    def cross_fit(cls, frames: Sequence[Any], *, folds: int = FOLDS, lambdas: Sequence[float] = LAMBDAS) -> EgoFit:
        """Cross-fit by scene on ``frames`` themselves (see the module docstring). UserError with fewer than 3 scenes."""
        from sklearn.model_selection import GroupKFold

        X, Y, scenes, ids = _arrays(frames)
        train_ok = _usable(X, Y)
        n_scenes = len(np.unique(scenes))
        if n_scenes < 3:
            raise UserError(
                f"baseline:ego cross-fits by scene and needs at least 3 scenes (each fold's λ is chosen by a scene "
                f"cross-validation inside the other folds); these frames hold {n_scenes}; run more scenes or "
                "fit on a training split (--fit-split train)"
            )
        k = min(folds, n_scenes)
        pred = np.full((len(ids), 12), np.nan)
        fold_records = []
        for number, (train, test) in enumerate(GroupKFold(n_splits=k).split(X, groups=scenes), start=1):
            train = train[train_ok[train]]
            fit = _Fit(X[train], Y[train], scenes[train], folds, lambdas)
            usable = test[_usable(X[test])]
            if len(usable):
                pred[usable] = fit.predict(X[usable])
            held_out = sorted(str(s) for s in np.unique(scenes[test]))
            assert not set(held_out) & set(fit.scenes)  # a fold is never predicted by a fit that saw its scenes
            fold_records.append(
                {"fold": number, "predicted_scenes": held_out, "predicted_frames": int(len(test)), **fit.record()}
            )
        record: dict[str, Any] = {
            "method": f"cross-fit by scene ({k} folds, GroupKFold), λ by nested scene CV",
            "folds": fold_records,
        }
        warning = small_fit_warning([(f["fit_scenes"], f["fit_frames"]) for f in fold_records], "each fold's fit")
        return cls._make(ids, X, pred, {**record, "warning": warning} if warning else record)

    @classmethod
    def fit_split(
        cls,
        train_frames: Frames,
        frames: Sequence[Any],
        *,
        split: str,
        folds: int = FOLDS,
        lambdas: Sequence[float] = LAMBDAS,
    ) -> EgoFit:
        """One fit on ``train_frames`` (the ``split`` split), predicting ``frames``; UserError when they share a scene."""
        Xt, Yt, scenes_t, _ = _arrays(train_frames)
        X, _, scenes, ids = _arrays(frames)
        shared = sorted(set(scenes_t.tolist()) & set(scenes.tolist()))
        if shared:
            raise UserError(
                f"baseline:ego --fit-split {split}: {len(shared)} evaluated scene(s) are in the training split too "
                f"({', '.join(shared[:3])}{', …' if len(shared) > 3 else ''}); evaluate another split (e.g. --split val)"
            )
        ok = _usable(Xt, Yt)
        if not ok.any():
            raise UserError(
                f"baseline:ego --fit-split {split}: the split has no frame with a finite history and future"
            )
        fit = _Fit(Xt[ok], Yt[ok], scenes_t[ok], folds, lambdas)
        pred = np.full((len(ids), 12), np.nan)
        usable = _usable(X)
        if usable.any():
            pred[usable] = fit.predict(X[usable])
        record: dict[str, Any] = {
            "method": f"one fit on the {split!r} split, λ by {fit.inner_folds}-fold scene CV",
            "fit_split": split,
            "fit": fit.record(),
        }
        warning = small_fit_warning([(len(fit.scenes), fit.frames)], f"the fit on {split!r}")
        return cls._make(ids, X, pred, {**record, "warning": warning} if warning else record)
