"""Synthetic run directories in the run-record format (docs/definitions.md#run-records), for tests, benchmarks and docs.

Ground truth comes from random (speed, curvature) profiles; a "model" adds
noise of a chosen size to the true actions, answers with a format error at a
chosen rate and fails for good at another. Nothing here touches a dataset.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from lightemma import integrate
from lightemma.definitions import STEP_SECONDS
from lightemma.runs.store import FRAMES_FILE, create_run_dir, update_manifest


def make_record(
    frame_id: str,
    gt_positions: Any,
    trajectory: Any,
    *,
    actions: Any = None,
    history_actions: Any = None,
    status: str = "ok",
    first_status: str | None = None,
    seconds: float = 1.0,
    input_tokens: int | None = 1000,
    output_tokens: int | None = 100,
    cost_cents: float | None = None,
    scene_name: str = "scene-0001",
    texts: Mapping[str, str] | None = None,
) -> dict[str, Any]:
    """One ``frames.jsonl`` record (docs/definitions.md#run-records) with the given values and one attempt."""
    texts = dict(texts or {})
    first = first_status or status
    answer = texts.get("answer", "")
    return {
        "frame_id": frame_id,
        "scene_name": scene_name,
        "sample_token": f"token-{frame_id}",
        "status": status,
        "first_status": first,
        "attempts": [
            {
                "answer": answer,
                "status": first,
                "reason": "" if first == "ok" else "synthetic",
                "input_tokens": input_tokens,
                "output_tokens": output_tokens,
                "seconds": seconds,
                "cost_cents": cost_cents,
            }
        ],
        "actions": None if actions is None else np.asarray(actions, dtype=float).tolist(),
        "trajectory": None if trajectory is None else np.asarray(trajectory, dtype=float).tolist(),
        "gt_positions": np.asarray(gt_positions, dtype=float).tolist(),
        "history_actions": np.zeros((6, 2)).tolist()
        if history_actions is None
        else np.asarray(history_actions, dtype=float).tolist(),
        "seconds": seconds,
        "input_tokens": input_tokens,
        "output_tokens": output_tokens,
        "cost_cents": cost_cents,
        "scene_text": texts.get("scene", "synthetic scene"),
        "intent_text": texts.get("intent", "synthetic intent"),
        "answer": answer,
        "cached": False,
    }


def synthetic_records(
    n_frames: int,
    *,
    seed: int = 0,
    noise: float = 0.5,
    fe_rate: float = 0.05,
    fail_rate: float = 0.01,
    cost_cents: float | None = 1.0,
    text_chars: int = 200,
    frames_per_scene: int = 26,
    batch: int = 4096,
) -> Iterator[dict[str, Any]]:
    """Yield ``n_frames`` records; frame ids ``scene-XXXX/K`` are the same for every seed."""
    rng = np.random.default_rng(seed)
    truth = np.random.default_rng(12345)  # ground truth independent of the model seed
    filler = ("the road ahead is clear with parked cars on the right " * (1 + text_chars // 50))[:text_chars]
    for start in range(0, n_frames, batch):
        n = min(batch, n_frames - start)
        # always draw a whole batch so that frame k has the same truth whatever n_frames is
        v0 = truth.uniform(0.0, 14.0, batch)[:n]
        acc = truth.uniform(-2.0, 1.5, batch)[:n]
        curv = (truth.normal(0.0, 0.03, batch) * (truth.random(batch) < 0.4))[:n]
        steps = np.arange(1, 7) * STEP_SECONDS
        gt_act = np.stack(
            [np.clip(v0[:, None] + acc[:, None] * steps, 0.0, None), np.repeat(curv[:, None], 6, 1)], axis=2
        )
        hist = np.stack(
            [np.clip(v0[:, None] - acc[:, None] * steps[::-1], 0.0, None), np.repeat(curv[:, None] * 0.8, 6, 1)], axis=2
        )
        pred_act = gt_act + np.stack([rng.normal(0, noise, (n, 6)), rng.normal(0, noise * 0.01, (n, 6))], axis=2)
        pred_act[..., 0] = np.clip(pred_act[..., 0], 0.0, None)
        gt, pred = integrate(gt_act, method="euler"), integrate(pred_act, method="euler")
        u = rng.random(n)
        failed = rng.random(n) < fail_rate
        for i in range(n):
            index = start + i
            first = "ok" if u[i] >= fe_rate else ("failed" if u[i] < fe_rate * 0.1 else "corrected")
            status = "failed" if failed[i] else ("ok" if first == "ok" else "corrected")
            ok = status != "failed"
            yield make_record(
                f"scene-{index // frames_per_scene:04d}/{7 + index % frames_per_scene}",
                gt[i],
                pred[i] if ok else None,
                actions=pred_act[i] if ok else None,
                history_actions=hist[i],
                status=status,
                first_status=first,
                seconds=float(rng.uniform(0.5, 3.0)),
                input_tokens=int(rng.integers(3000, 7000)),
                output_tokens=int(rng.integers(200, 700)),
                cost_cents=None if cost_cents is None else float(cost_cents * rng.uniform(0.5, 1.5)),
                scene_name=f"scene-{index // frames_per_scene:04d}",
                texts={
                    "scene": filler,
                    "intent": filler,
                    "answer": "[" + ", ".join(f"({v:.3f}, {c:.4f})" for v, c in pred_act[i]) + "]",
                },
            )


def write_synthetic_run(
    output: str | os.PathLike[str],
    model: str,
    n_frames: int,
    *,
    seed: int = 0,
    manifest: Mapping[str, Any] | None = None,
    finished: bool = True,
    **record_options: Any,
) -> Path:
    """Create a run directory of ``n_frames`` synthetic records; returns its path.

    ``record_options`` go to :func:`synthetic_records`. Lines are written in
    large buffered blocks (fast enough for a million records).
    """
    base = {
        "model": model,
        "started_at": "2026-01-01T00:00:00+00:00",
        "integrator": "euler",
        "concurrency": 8,
        "backend": {"kind": "synthetic", "gpus": None},
    }
    run_dir = create_run_dir(output, model, {**base, **dict(manifest or {})})
    with open(run_dir / FRAMES_FILE, "w", encoding="utf-8") as fh:
        block: list[str] = []
        for record in synthetic_records(n_frames, seed=seed, **record_options):
            block.append(json.dumps(record))
            if len(block) >= 4096:
                fh.write("\n".join(block) + "\n")
                block.clear()
        if block:
            fh.write("\n".join(block) + "\n")
    if finished:
        update_manifest(run_dir, finished_at="2026-01-01T00:10:00+00:00", wall_seconds=600.0)
    return run_dir
