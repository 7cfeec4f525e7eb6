"""A synthetic *study*: many models over many scenes, with the mess of real runs.

:func:`write_study` writes run directories (the ordinary run format, one per
model) over synthetic scenes driven at 2 Hz with:

* scenes of cruising, turns and stops (the ego halts and waits: near-stationary
  frames whose ground-truth positions, with 1 cm of pose noise, give Menger
  curvatures of ±90 1/m — the trap of the history-bias analysis);
* history actions computed from the noisy poses exactly as the frame loader does
  (the paper's post-processing, docs/definitions.md#history), ground truth in each frame's ego frame;
* models whose errors have a known structure: a per-model error scale, a
  multiplicative scene difficulty shared by all models (lognormal, σ = ``scene_sd``)
  times a model-specific scene effect (lognormal, σ = ``model_scene_sd``), a
  history bias (the predicted curvature leans on the last history curvature);
* outcomes of real runs: format errors, API errors, and a model answering
  garbage (speeds of 1e12 m/s, ADE ≈ 1e12 m) on a share of its frames — marked
  ``failure: "implausible"`` as the current parser does, or not marked at all as
  older runs are.

Used by the tests (realistic fixtures), the benchmarks and to look at reports.
Nothing here touches a dataset or the network.
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from lightemma.definitions import STEP_SECONDS
from lightemma.kinematics import integrate
from lightemma.nuscenes import geometry
from lightemma.runs.store import FRAMES_FILE, create_run_dir, update_manifest

POSE_NOISE = 0.01  # m, per keyframe position
GARBAGE_SPEED = 1e12


@dataclass(frozen=True)
class StudyModel:
    """One synthetic model: how wrong it is, how it fails, what it costs."""

    model: str  # model string (a registry id makes family and generation known)
    speed_error: float = 0.8  # m/s: sd of the frame's speed offset (the main source of ADE)
    curvature_error: float = 0.004  # 1/m: sd of per-step curvature noise
    history_bias: float = 0.3  # weight of the last history curvature in the predicted curvature
    fe_rate: float = 0.01  # first answer not strictly parseable (re-asked, then fine)
    fail_rate: float = 0.002  # final format failure
    api_error_rate: float = 0.0  # frames lost to API errors
    garbage_rate: float = 0.0  # answers of 1e12 m/s
    garbage_marked: bool = True  # garbage frames recorded as failure "implausible" (else status ok, unmarked)
    seconds: float = 10.0  # mean time per frame
    input_tokens: int = 5000
    output_tokens: int = 400
    cost_cents: float | None = 1.0
    manifest: dict[str, Any] = field(default_factory=dict)


# (model id, ADE-scale, seconds, input tokens, output tokens, cost ¢) after the paper's Tables I and II
_PAPER_LIKE: tuple[tuple[str, float, float, int, int, float | None], ...] = (
    ("gpt-4o", 1.07, 12.1, 4402, 341, 1.40),
    ("gpt-5", 1.07, 15.3, 3922, 440, 0.93),
    ("gpt-5.2", 1.17, 11.6, 6375, 400, 1.68),
    ("anthropic/claude-3-7-sonnet-20250219", 1.08, 14.8, 5948, 461, 2.47),
    ("anthropic/claude-sonnet-4-20250514", 1.25, 17.0, 6074, 540, 2.63),
    ("anthropic/claude-sonnet-4-6", 1.44, 22.2, 6238, 660, 2.76),
    ("gemini/gemini-2.0-flash", 1.25, 4.5, 6398, 272, 0.07),
    ("gemini/gemini-2.5-flash", 1.54, 28.5, 1968, 402, 1.35),
    ("gemini/gemini-3-flash-preview", 1.10, 31.0, 4484, 404, 0.35),
    ("Qwen/Qwen2-VL-7B-Instruct", 1.69, 9.1, 6593, 341, None),
    ("Qwen/Qwen2.5-VL-7B-Instruct", 1.45, 8.8, 6554, 318, None),
    ("Qwen/Qwen3-VL-8B-Instruct", 1.21, 12.8, 5359, 375, None),
    ("meta-llama/Llama-3.2-11B-Vision-Instruct", 1.53, 7.5, 1039, 313, None),
)


def paper_like_models(
    *,
    garbage: str = "meta-llama/Llama-3.2-11B-Vision-Instruct",
    garbage_rate: float = 0.5,
    garbage_marked: bool = True,
    count: int = 13,
) -> list[StudyModel]:
    """Thirteen models named like the paper's, with error scales after its Table II (ADE ≈ 1.4 × speed error).

    ``garbage`` answers 1e12 m/s on ``garbage_rate`` of its frames; Gemini-2.5-Flash
    loses 1 % of its frames to API errors.
    """
    out = []
    for model, ade, secs, inp, outp, cost in _PAPER_LIKE[:count]:
        out.append(
            StudyModel(
                model=model,
                speed_error=ade / 1.4,
                seconds=secs,
                input_tokens=inp,
                output_tokens=outp,
                cost_cents=cost,
                api_error_rate=0.01 if "2.5-flash" in model else 0.0,
                garbage_rate=garbage_rate if model == garbage else 0.0,
                garbage_marked=garbage_marked,
            )
        )
    return out


@dataclass
class StudyScenes:
    """The shared truth of a study: per frame ids, scenes, ground truth, history, true future actions."""

    frame_ids: list[str]
    scene_names: list[str]
    scene_index: np.ndarray  # (N,)
    gt_positions: np.ndarray  # (N, 6, 2)
    history_actions: np.ndarray  # (N, 6, 2)
    future_actions: np.ndarray  # (N, 6, 2) noise-free simulated actions of the next 3 s
    difficulty: np.ndarray  # (scenes,) multiplicative scene difficulty shared by all models

    def __len__(self) -> int:
        return len(self.frame_ids)


def _scene_drive(rng: np.random.Generator, steps: int) -> np.ndarray:
    """(steps, 2) noise-free (speed, curvature) actions of one scene at 0.5 s."""
    v = np.clip(rng.uniform(3.0, 13.0) + np.cumsum(rng.normal(0.0, 0.2, steps)), 0.0, 16.0)
    kappa = rng.normal(0.0, 0.0015, steps)
    kind = rng.choice(["cruise", "turns", "stop", "stop_turn"], p=[0.3, 0.35, 0.2, 0.15])
    if kind in ("turns", "stop_turn"):
        for _ in range(int(rng.integers(1, 3))):
            start = int(rng.integers(0, max(1, steps - 6)))
            k = rng.choice([-1.0, 1.0]) * rng.uniform(0.04, 0.15)
            turn_speed = rng.uniform(3.0, 7.0)
            length = int(np.clip(round((np.pi / 2) / (abs(k) * turn_speed * STEP_SECONDS)), 3, 16))
            kappa[start : start + length] += k
            v[start : start + length] = np.minimum(v[start : start + length], turn_speed)
    if kind in ("stop", "stop_turn"):
        stop = int(rng.integers(6, max(7, steps - 8)))
        brake = int(rng.integers(3, 7))
        wait = int(rng.integers(4, 18))
        before = v[max(0, stop - brake)]
        v[max(0, stop - brake) : stop] = np.linspace(before, 0.0, stop - max(0, stop - brake) + 1)[1:]
        v[stop : stop + wait] = 0.0
        go = v[stop + wait : stop + wait + 8]
        v[stop + wait : stop + wait + len(go)] = np.minimum(go, np.linspace(0.8, 8.0, len(go)))
    kappa[v < 0.05] = 0.0
    return np.stack([v, kappa], axis=1)


def study_scenes(
    n_scenes: int = 150, frames_per_scene: int = 26, *, seed: int = 0, scene_sd: float = 0.35
) -> StudyScenes:
    """Simulate ``n_scenes`` drives and cut them into frames (reference window: c = 7 … K − 8)."""
    rng = np.random.default_rng([seed, 7001])
    keyframes = frames_per_scene + 14
    ids, names, index, gts, hists, futures = [], [], [], [], [], []
    for s in range(n_scenes):
        actions = _scene_drive(rng, keyframes - 1)
        positions = np.concatenate([np.zeros((1, 2)), integrate(np.ascontiguousarray(actions), method="midpoint")])
        heading = np.concatenate([[0.0], np.cumsum(actions[:, 0] * actions[:, 1] * STEP_SECONDS)])
        turn = rng.uniform(-np.pi, np.pi)  # the scene's direction on the map
        rot = np.array([[np.cos(turn), -np.sin(turn)], [np.sin(turn), np.cos(turn)]])
        world = positions @ rot.T + rng.uniform(-500, 500, 2) + rng.normal(0.0, POSE_NOISE, positions.shape)
        yaw = heading + turn + rng.normal(0.0, 0.002, len(heading))
        current = np.arange(7, keyframes - 7)  # reference window: N − 14 frames
        idx = current[:, None] + np.arange(-7, 7)[None, :]
        ego = geometry.to_ego_frame(world[idx], world[current], yaw[current])
        stamps = idx * 500_000
        hists.append(geometry.postprocess_reference(geometry.raw_actions(ego[:, :8], stamps[:, :8])))
        gts.append(ego[:, 8:14])
        futures.append(actions[current[:, None] + np.arange(6)[None, :]])
        name = f"scene-{s:04d}"
        ids += [f"{name}/{c:02d}" for c in current]
        names.append(name)
        index.append(np.full(len(current), s))
    difficulty = np.exp(rng.normal(0.0, scene_sd, n_scenes))
    return StudyScenes(
        ids,
        names,
        np.concatenate(index),
        np.concatenate(gts),
        np.concatenate(hists),
        np.concatenate(futures),
        difficulty,
    )


def predict(
    scenes: StudyScenes, model: StudyModel, *, seed: int = 0, model_scene_sd: float = 0.15
) -> dict[str, np.ndarray]:
    """A model's predicted actions and trajectories (N, 6, 2) and outcome masks, reproducible per model string."""
    rng = np.random.default_rng([seed, *model.model.encode()])
    n = len(scenes)
    own = np.exp(rng.normal(0.0, model_scene_sd, len(scenes.scene_names)))
    scale = (scenes.difficulty * own)[scenes.scene_index]
    truth = scenes.future_actions
    speed = truth[..., 0] + (model.speed_error * scale)[:, None] * (
        rng.normal(0.0, 1.0, (n, 1)) + 0.3 * rng.normal(0.0, 1.0, (n, 6))
    )
    curvature = (1 - model.history_bias) * truth[..., 1] + model.history_bias * scenes.history_actions[:, -1:, 1]
    curvature = curvature + model.curvature_error * scale[:, None] * rng.normal(0.0, 1.0, (n, 6))
    actions = np.stack([np.clip(speed, 0.0, None), curvature], axis=2)
    u = rng.random((4, n))
    garbage = u[0] < model.garbage_rate
    actions[garbage] = [GARBAGE_SPEED, 0.0]
    return {
        "actions": actions,
        "trajectory": integrate(np.ascontiguousarray(actions), method="euler"),
        "garbage": garbage,
        "api_error": ~garbage & (u[1] < model.api_error_rate),
        "failed": ~garbage & (u[1] >= model.api_error_rate) & (u[2] < model.fail_rate),
        "fe": u[3] < model.fe_rate,
        "seconds": model.seconds * rng.uniform(0.6, 1.4, n),
        "input_tokens": rng.integers(int(model.input_tokens * 0.8), int(model.input_tokens * 1.2) + 1, n),
        "output_tokens": rng.integers(int(model.output_tokens * 0.7), int(model.output_tokens * 1.3) + 1, n),
    }


def _records(scenes: StudyScenes, model: StudyModel, p: dict[str, np.ndarray], record_failure: bool) -> Any:
    for i in range(len(scenes)):
        failure = (
            "api_error"
            if p["api_error"][i]
            else "format"
            if p["failed"][i]
            else "implausible"
            if p["garbage"][i] and model.garbage_marked
            else ""
        )
        failed = bool(failure)
        first = "failed" if failed else ("corrected" if p["fe"][i] else "ok")
        keep = not failed or failure == "implausible"  # an implausible answer keeps what was read
        record: dict[str, Any] = {
            "frame_id": scenes.frame_ids[i],
            "scene_name": scenes.scene_names[scenes.scene_index[i]],
            "sample_token": f"token-{i}",
            "status": "failed" if failed else ("corrected" if first == "corrected" else "ok"),
            "first_status": first,
            "actions": p["actions"][i].tolist() if keep else None,
            "trajectory": p["trajectory"][i].tolist() if keep and not failed else None,
            "gt_positions": scenes.gt_positions[i].tolist(),
            "history_actions": scenes.history_actions[i].tolist(),
            "seconds": float(p["seconds"][i]),
            "input_tokens": int(p["input_tokens"][i]),
            "output_tokens": int(p["output_tokens"][i]),
            "cost_cents": None
            if model.cost_cents is None
            else float(model.cost_cents * p["seconds"][i] / model.seconds),
            "scene_text": "synthetic scene",
            "intent_text": "synthetic intent",
            "answer": "garbage"
            if p["garbage"][i]
            else "[" + ", ".join(f"({v:.3f}, {c:.4f})" for v, c in p["actions"][i]) + "]",
            "error": "APIError: synthetic" if failure == "api_error" else None,
        }
        if record_failure:
            record["failure"] = failure
        yield record


def write_study(
    output: str | os.PathLike[str],
    models: Sequence[StudyModel],
    *,
    n_scenes: int = 150,
    frames_per_scene: int = 26,
    seed: int = 0,
    record_failure: bool = True,
    scenes: StudyScenes | None = None,
) -> list[Path]:
    """Write one run directory per model under ``output``; returns them.

    ``record_failure=False`` leaves the ``failure`` field out (runs written
    before it existed; unmarked garbage is then ``ok``).
    """
    scenes = scenes or study_scenes(n_scenes, frames_per_scene, seed=seed)
    dirs = []
    for model in models:
        if not record_failure:
            model = replace(model, garbage_marked=False)
        manifest = {
            "model": model.model,
            "integrator": "euler",
            "concurrency": 32,
            "backend": {"kind": "synthetic-study"},
            **model.manifest,
        }
        run_dir = create_run_dir(output, model.model, manifest)
        with open(run_dir / FRAMES_FILE, "w", encoding="utf-8") as fh:
            fh.writelines(
                json.dumps(r) + "\n" for r in _records(scenes, model, predict(scenes, model, seed=seed), record_failure)
            )
        update_manifest(
            run_dir,
            started_at="2026-01-01T00:00:00+00:00",
            finished_at="2026-01-01T02:00:00+00:00",
            wall_seconds=7200.0,
        )
        dirs.append(run_dir)
    return dirs
