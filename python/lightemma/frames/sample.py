"""A reproducible sample of frames spread over as many scenes as possible (``lightemma run --sample N``).

``--limit N`` takes the first N frames in scene order — on a small set, one scene, and a scene-level
bootstrap interval needs at least two. :func:`sample_frames` instead visits the scenes in an order shuffled
by ``seed`` and takes one frame from each (chosen by the same generator) round after round, until N frames
are taken: N ≥ the number of scenes covers every scene; fewer covers N distinct scenes. The frames come
back in the set's own order (scene, then keyframe). Same frames + same N + same seed = the same sample.
``lightemma run --sample N`` refuses an N above the set's size (it would record N frames it did not take).
"""

from __future__ import annotations

import random
from collections.abc import Sequence
from typing import Any

from lightemma.errors import UserError


def sample_indices(scene_names: Sequence[str], n: int, seed: int = 0) -> list[int]:
    """Indices (ascending) of ``n`` frames spread over the scenes of ``scene_names`` (one entry per frame)."""
    if n < 1:
        raise UserError(f"--sample must be at least 1, got {n}")
    by_scene: dict[str, list[int]] = {}
    for i, scene in enumerate(scene_names):
        by_scene.setdefault(str(scene), []).append(i)
    rng = random.Random(seed)
    scenes = sorted(by_scene)
    rng.shuffle(scenes)
    pools = {s: rng.sample(by_scene[s], len(by_scene[s])) for s in scenes}  # each scene's frames in a seeded order
    taken: list[int] = []
    while len(taken) < min(n, len(scene_names)):
        for scene in scenes:
            if pools[scene] and len(taken) < n:
                taken.append(pools[scene].pop())
    return sorted(taken)


def sample_frames(frames: Any, n: int, seed: int = 0) -> Any:
    """``n`` frames of ``frames`` (a FrameSet or any sequence of Frame-like objects) spread over its scenes.

    A FrameSet comes back as a FrameSet; other sequences as a list. ``n`` at or above the set's size
    keeps every frame.
    """
    names = list(frames.scene_names) if hasattr(frames, "scene_names") else [f.scene_name for f in frames]
    keep = sample_indices(names, n, seed)
    if hasattr(frames, "select") and hasattr(frames, "frame_ids"):
        return frames.select([frames.frame_ids[i] for i in keep])
    items = list(frames)
    return [items[i] for i in keep]


def describe_sample(frames: Any, n: int, seed: int) -> dict[str, Any]:
    """What the manifest records of a sample: N asked, seed, frames and scenes taken, the rule."""
    names = list(frames.scene_names) if hasattr(frames, "scene_names") else [f.scene_name for f in frames]
    return {
        "n": int(n),
        "seed": int(seed),
        "frames": len(names),
        "scenes": len(set(names)),
        "rule": "one frame per scene per round, scenes in a seeded order (lightemma.frames.sample)",
    }
