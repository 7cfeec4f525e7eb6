"""K samples per frame (``lightemma run --samples K``): minADE@K, minFDE@K and the spread of the K trajectories.

Definitions (docs/definitions.md#k-samples): a frame is scored when its sample-0 prediction is (the frame's usual
ADE rules); its K samples are sample 0's trajectory and those of the samples 1..K-1 the record's ``samples`` list
holds with a status other than ``failed`` and a finite trajectory within :data:`~lightemma.runs.records.MAX_POSITION_M`
(a sample without one is left out of that frame's minimum). Per convention:

* ``minade``: the mean over the scored frames of min over the frame's samples of that convention's per-frame
  ADE (``ade_avg``, :func:`lightemma.metrics.frame_metrics`) — minADE@K as in the Waymo Open Dataset end-to-end
  driving challenge (WOD-E2E, arXiv:2510.26125) and Alpamayo-R1 (arXiv:2511.00088);
* ``minfde``: the same with the final displacement error (``fde``), minimised on its own;
* ``spread_m``: the mean, over the scored frames with at least two samples, of the mean pairwise distance (m)
  between the samples' final points (0 when every sample is the same plan).

The samples are read as recorded (a re-parse with ``--parse`` or ``--keep-implausible`` re-reads sample 0 only).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from lightemma.evaluation.loading import RunData, read_frame_records
from lightemma.metrics import FRAME_METRICS, frame_metrics
from lightemma.runs.records import MAX_POSITION_M


def run_samples(run: RunData) -> int:
    """K, the samples per frame the run's manifest records (``params.samples``; 1 without)."""
    params = (run.info.manifest or {}).get("params")
    k = params.get("samples") if isinstance(params, dict) else None
    return k if type(k) is int and k > 1 else 1


def sample_trajectories(run: RunData, rows: np.ndarray) -> np.ndarray:
    """(len(rows), K, 6, 2) trajectories of the frames ``rows`` of ``run``: sample 0 is ``run.trajectory``, the
    others as their records hold them; NaN where a sample has no usable trajectory (see the module docstring)."""
    k = run_samples(run)
    out = np.full((len(rows), k, 6, 2), np.nan)
    if len(rows) == 0:
        return out
    out[:, 0] = run.trajectory[rows]
    if k == 1:
        return out
    ids = [run.frame_ids[int(r)] for r in rows]
    records = read_frame_records(run.info.run_dir, ids)
    for i, fid in enumerate(ids):
        for entry in (records.get(fid) or {}).get("samples") or ():
            s = entry.get("sample") if isinstance(entry, dict) else None
            if type(s) is not int or not 0 < s < k or entry.get("status") == "failed":
                continue
            try:
                traj = np.asarray(entry.get("trajectory"), dtype=np.float64)
            except (TypeError, ValueError):
                continue
            if traj.shape == (6, 2) and np.isfinite(traj).all() and np.abs(traj).max() <= MAX_POSITION_M:
                out[i, s] = traj
    return out


def _mean(values: np.ndarray) -> float | None:
    return float(values.mean()) if len(values) else None


def sample_metrics(run: RunData, rows: np.ndarray, conventions: tuple[str, ...]) -> dict[str, dict[str, Any]]:
    """Per convention ``{"samples": K, "minade", "minfde", "spread_m", "sampled_frames"}`` over the scored frames
    ``rows``; an empty dict for a run of one sample per frame (its rows stay as they were)."""
    k = run_samples(run)
    if k == 1:
        return {}
    trajs = sample_trajectories(run, rows)
    gt = run.gt_positions[rows]
    have = np.isfinite(trajs).all(axis=(2, 3))  # (n, K)
    finals = trajs[:, :, -1, :]  # (n, K, 2)
    spreads = []
    for i in range(len(rows)):
        points = finals[i][have[i]]
        if len(points) >= 2:
            d = np.linalg.norm(points[:, None, :] - points[None, :, :], axis=-1)
            spreads.append(d[np.triu_indices(len(points), 1)].mean())
    ade_col, fde_col = FRAME_METRICS.index("ade_avg"), FRAME_METRICS.index("fde")
    out: dict[str, dict[str, Any]] = {}
    for convention in conventions:
        ade = np.full((len(rows), k), np.inf)
        fde = np.full((len(rows), k), np.inf)
        for s in range(k):
            ok = have[:, s]
            if ok.any():
                values = frame_metrics(trajs[ok, s], gt[ok], convention=convention)
                ade[ok, s], fde[ok, s] = values[:, ade_col], values[:, fde_col]
        out[convention] = {
            "samples": k,
            "minade": _mean(ade.min(axis=1)),
            "minfde": _mean(fde.min(axis=1)),
            "spread_m": _mean(np.asarray(spreads)),
            "sampled_frames": int(have[:, 1:].any(axis=1).sum()),
        }
    return out


def best_and_mean(run: RunData, rows: np.ndarray, convention: str) -> tuple[RunData, RunData] | None:
    """Two copies of ``run`` whose trajectories at ``rows`` are the best sample (lowest ADE under ``convention``)
    and the mean of the frame's samples (point by point), for the safety and planning evaluations; None for a
    run of one sample per frame."""
    if run_samples(run) == 1 or len(rows) == 0:
        return None
    trajs = sample_trajectories(run, rows)
    have = np.isfinite(trajs).all(axis=(2, 3))
    ade = np.full(have.shape, np.inf)
    col = FRAME_METRICS.index("ade_avg")
    for s in range(trajs.shape[1]):
        ok = have[:, s]
        if ok.any():
            ade[ok, s] = frame_metrics(trajs[ok, s], run.gt_positions[rows][ok], convention=convention)[:, col]
    best_traj = run.trajectory.copy()
    best_traj[rows] = trajs[np.arange(len(rows)), ade.argmin(axis=1)]
    mean_traj = run.trajectory.copy()
    mean_traj[rows] = np.nanmean(np.where(have[:, :, None, None], trajs, np.nan), axis=1)
    return replace(run, trajectory=best_traj), replace(run, trajectory=mean_traj)
