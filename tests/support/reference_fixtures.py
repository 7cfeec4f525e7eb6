"""Result folders in the LightEMMA reference scripts' format, written by tests (invented values).

The shapes are the format's (docs/import.md): ``<results>/<model>/output/<scene>.json``,
long texts as lists of lines of at most 80 characters, tokens and seconds per
stage, optional ``metadata`` / ``gt_actions`` / ``predictions`` / ``analysis/``,
``image_name`` in newer versions and ``image_path`` in older ones.

The prompt wording below is this test suite's own (with the reference's
layout quirks: no space before the printed speed list, a double space) and
:data:`PROMPT_SET` is the lightemma prompt set that reproduces it.
"""

from __future__ import annotations

import hashlib
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

SCENE_PROMPT = (
    "You label driving data for an autonomous car. You see the image of the front camera. "
    "Watch the other cars, the people on foot, the lane lines, the signals and anything else that matters, "
    "and say what they do; do not guess what the ego car does.  One plain paragraph, no lists. "
)
INTENT_TEMPLATE = (
    "You label driving data for an autonomous car. You see the image of the front camera. "
    "What the scene holds: {scene} "
    "Ego speed over the last 3 seconds, every 0.5 s, was{speeds} m/s (newest last). "
    "Ego curvature over the same time was{curvatures} (newest last). "
    "Positive curvature is a left turn, negative a right turn. "
    "What did the ego car mean to do, and what should it do in the next 3 seconds? One plain paragraph. "
)
ACTIONS_TEMPLATE = (
    "You label driving data for an autonomous car. You see the image of the front camera. "
    "What the scene holds: {scene} "
    "Ego speed over the last 3 seconds, every 0.5 s, was{speeds} m/s (newest last). "
    "Ego curvature over the same time was{curvatures} (newest last). "
    "Positive curvature is a left turn, negative a right turn. "
    "The plan: {intent} "
    "Give speed and curvature for the next 6 steps of 0.5 s as "
    "[(v1, c1), (v2, c2), (v3, c3), (v4, c4), (v5, c5), (v6, c6)] and nothing else."
)
PROMPT_SET = {
    "name": "fixture-reference",
    "description": "the wording of tests/support/reference_fixtures.py",
    "stages": {"scene": SCENE_PROMPT, "intent": INTENT_TEMPLATE, "actions": ACTIONS_TEMPLATE},
}

SCENES = (
    "The road ahead is a two-lane street with a white sedan parked on the right and a cyclist in the bike lane.",
    "A bus waits at the stop on the left.\nTwo pedestrians cross at the far crosswalk while the signal shows green.",
    "Wide intersection; the light is red, a truck turns left in front, cones narrow the right lane near a work zone.",
)
INTENTS = (
    "The ego car kept its lane at a steady speed; it should keep following the lane and hold about the same speed.",
    "The ego car was slowing for the light and should come to a smooth stop behind the truck over the next seconds.",
)


def format_long_text(text: str, max_line_length: int = 80) -> list[str]:
    """How the reference scripts store a long text: one entry per short line, long lines split into words."""
    result: list[str] = []
    for paragraph in text.split("\n"):
        if not paragraph.strip():
            continue
        if len(paragraph) <= max_line_length:
            result.append(paragraph.strip())
            continue
        line: list[str] = []
        length = 0
        for word in paragraph.split():
            if length + len(word) + (1 if length > 0 else 0) > max_line_length:
                if line:
                    result.append(" ".join(line))
                line, length = [word], len(word)
            else:
                line.append(word)
                length += len(word) + (1 if length > 0 else 0)
        if line:
            result.append(" ".join(line))
    return result


def euler(actions: list[list[float]], dt: float = 0.5) -> list[list[float]]:
    """The paper's equations 1-3 in plain Python."""
    x = y = heading = 0.0
    out = []
    for v, k in actions:
        x += v * math.cos(heading) * dt
        y += v * math.sin(heading) * dt
        heading += k * v * dt
        out.append([x, y])
    return out


def strict_answer(actions: list[list[float]]) -> str:
    return "[" + ", ".join(f"({v}, {c})" for v, c in actions) + "]"


def _history(rng: np.random.Generator) -> tuple[list[list[Any]], list[list[float]]]:
    """Six (speed, curvature) history pairs as the reference rounds them, and 8 ego-frame positions ending at the origin."""
    v0 = float(rng.uniform(0.0, 12.0))
    speeds = [round(max(0.0, v0 + float(rng.normal(0, 0.4))), 3) for _ in range(6)]
    speeds = [0.0 if s < 0.2 else s for s in speeds]
    curvatures: list[Any] = [round(float(rng.normal(0, 0.02)), 3) for _ in range(6)]
    if rng.random() < 0.3:
        curvatures[0] = -0.0  # the reference zeroes a large negative curvature to -0.0
    if rng.random() < 0.2:
        curvatures[1] = 0  # a degenerate triangle: the reference writes an int 0
    positions = [[-0.5 * v0 * (7 - k), float(rng.normal(0, 0.05))] for k in range(7)] + [
        [-0.0 if rng.random() < 0.5 else 0.0, 0.0]
    ]
    return [[s, c] for s, c in zip(speeds, curvatures)], positions


def make_frame(
    rng: np.random.Generator,
    scene_name: str,
    index: int,
    *,
    answer: str | None = None,
    image_key: str = "image_name",
    gt_actions: bool = True,
    predictions: bool = True,
    tokens: bool = True,
) -> dict[str, Any]:
    """One frame of a scene file. ``answer`` overrides the model's stage-3 answer (default: a strict list near the truth)."""
    history, obs_positions = _history(rng)
    v = history[-1][0]
    true_actions = [
        [max(0.0, v + float(rng.normal(0, 0.5)) * (k + 1) / 3), float(rng.normal(0, 0.01))] for k in range(6)
    ]
    gt_positions = euler(true_actions)
    predicted = [
        [round(a + float(rng.normal(0, 0.6)), 2), round(c + float(rng.normal(0, 0.004)), 4)] for a, c in true_actions
    ]
    answer = strict_answer(predicted) if answer is None else answer
    scene = SCENES[index % len(SCENES)]
    intent = INTENTS[index % len(INTENTS)]
    speeds = repr([s for s, _ in history])
    curvatures = repr([c for _, c in history])
    intent_prompt = INTENT_TEMPLATE.format(scene=scene, speeds=speeds, curvatures=curvatures)
    actions_prompt = ACTIONS_TEMPLATE.format(scene=scene, speeds=speeds, curvatures=curvatures, intent=intent)
    token = hashlib.md5(f"{scene_name}/{index}".encode()).hexdigest()
    stamp = 1533150000012404 + 500000 * (index + 7)
    image = f"n008-2018-08-01-15-16-36-0400__CAM_FRONT__{stamp}.jpg"
    frame: dict[str, Any] = {"frame_index": index, "sample_token": token}
    if image_key in ("image_name", "both"):
        frame["image_name"] = image
    if image_key in ("image_path", "both"):
        frame["image_path"] = f"/data/nuscenes/samples/CAM_FRONT/{image}"
    frame.update(
        {
            "timestamp": stamp,
            "camera_params": {
                "rotation": [0.4998, -0.5030, 0.4997, -0.4973],
                "translation": [1.7008, 0.0159, 1.5110],
                "camera_intrinsic": [[1266.4, 0.0, 816.3], [0.0, 1266.4, 491.5], [0.0, 0.0, 1.0]],
            },
            "ego_info": {
                "position": [float(rng.uniform(300, 2000)), float(rng.uniform(300, 2000))],
                "heading": float(rng.uniform(-math.pi, math.pi)),
                "obs_positions": obs_positions,
                "obs_actions": history,
                "gt_positions": gt_positions,
            },
            "inference": {
                "scene_prompt": format_long_text(SCENE_PROMPT),
                "scene_description": format_long_text(scene),
                "intent_prompt": format_long_text(intent_prompt),
                "driving_intent": format_long_text(intent),
                "waypoint_prompt": format_long_text(actions_prompt),
                "pred_actions_str": answer,
            },
        }
    )
    if gt_actions:
        frame["ego_info"]["gt_actions"] = [[round(a, 3), round(c, 3)] for a, c in true_actions]
    if tokens:
        frame["token_usage"] = {
            stage: {"input": int(rng.integers(900, 2500)), "output": int(rng.integers(20, 200))}
            for stage in ("scene_prompt", "intent_prompt", "waypoint_prompt")
        }
        frame["time_usage"] = {
            stage: round(float(rng.uniform(0.5, 6.0)), 3)
            for stage in ("scene_prompt", "intent_prompt", "waypoint_prompt")
        }
    if predictions:
        frame["predictions"] = (
            {"pred_actions": predicted, "trajectory": euler(predicted)}
            if answer == strict_answer(predicted)
            else {"pred_actions_str": answer}
        )
    return frame


def write_scene(
    folder: Path,
    scene_name: str,
    frames: list[dict[str, Any]],
    *,
    metadata: dict[str, Any] | None = None,
    truncate: bool = False,
) -> Path:
    """Write one scene file (indent 4, as the reference's json.dump); ``truncate`` cuts it mid-way (invalid JSON)."""
    doc: dict[str, Any] = {
        "scene_info": {
            "name": scene_name,
            "description": "invented",
            "first_sample_token": "a" * 32,
            "last_sample_token": "b" * 32,
        }
    }
    if metadata is not None:
        doc["metadata"] = {**metadata, "total_frames": len(frames)}
    doc["frames"] = frames
    text = json.dumps(doc, indent=4, ensure_ascii=False)  # NaN is written as NaN, as Python's json does
    if truncate:
        text = text[: len(text) // 2]
    path = folder / "output" / f"{scene_name}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text, encoding="utf-8")
    return path


# answers with a known reading under the paper's rules
LIST_OF_LISTS = "[[4.1, 0.0], [4.3, 0.001], [4.4, 0.0], [4.6, -0.002], [4.8, 0.0], [5.0, 0.0]]"
PROSE = "Sure. The actions are [(3.5, 0.01), (3.6, 0.012), (3.8, 0.01), (4.0, 0.0), (4.1, 0.0), (4.2, -0.001)] for 3 s."
UNPARSEABLE = "I am unable to determine the vehicle's actions from this image."
TRUNCATED = "[(5.2, 0.0), (5.4, 0.0), (5.5, 0.001), (5.6, 0.0), (5.7, 0.0), (5.8, -0"
FIVE_PAIRS = "[(5.2, 0.0), (5.4, 0.0), (5.5, 0.001), (5.6, 0.0), (5.7, 0.0)]"
LOST_DECIMALS = "[(5254,0001),(5559,00005),(5600,0),(5700,0),(5800,0),(5900,0)]"
CALL_FAILED = "Error generating response: Rate limit reached for gpt-4o; please retry after 20s"


def write_results(root: Path, seed: int = 7) -> dict[str, Any]:
    """Several model folders with every variant the format has; returns what a correct import must report."""
    rng = np.random.default_rng(seed)
    meta = lambda model: {"model": model, "timestamp": "20250101-120000"}  # noqa: E731

    gpt = root / "gpt-4o"
    write_scene(
        gpt,
        "scene-0001",
        [make_frame(rng, "scene-0001", i, answer=PROSE if i == 2 else None) for i in range(8)],
        metadata=meta("gpt-4o"),
    )
    write_scene(
        gpt,
        "scene-0002",
        [
            make_frame(
                rng, "scene-0002", i, image_key="image_path", gt_actions=False, answer=UNPARSEABLE if i == 1 else None
            )
            for i in range(5)
        ],
    )  # an older version: no metadata
    write_scene(
        gpt, "scene-0003", [make_frame(rng, "scene-0003", i) for i in range(6)], metadata=meta("gpt-4o"), truncate=True
    )
    (gpt / "analysis").mkdir()
    (gpt / "analysis" / "evaluation.json").write_text('{"not": "a scene"}')

    claude = root / "claude-3.7-sonnet_20250101-120000"
    frames = [
        make_frame(rng, "scene-0001", i, predictions=False, answer=LIST_OF_LISTS if i == 3 else None) for i in range(8)
    ]
    frames[5]["ego_info"]["obs_actions"][2][1] = float("nan")  # a bad frame: not finite
    write_scene(claude, "scene-0001", frames, metadata=meta("claude-3.7"))
    frames = [
        make_frame(rng, "scene-0004", i, image_key="both", answer=TRUNCATED if i == 0 else None) for i in range(11)
    ]
    frames[7]["ego_info"]["gt_positions"] = frames[7]["ego_info"]["gt_positions"][
        :5
    ]  # a bad frame: 5 ground-truth points
    write_scene(claude, "scene-0004", frames, metadata=meta("claude-3.7"))

    qwen = root / "qwen-2.5-7b"
    answers = {0: FIVE_PAIRS, 2: LOST_DECIMALS, 4: LIST_OF_LISTS}
    write_scene(
        qwen,
        "scene-0001",
        [make_frame(rng, "scene-0001", i, tokens=i != 1, answer=answers.get(i)) for i in range(6)],
        metadata=meta("qwen2.5-7b"),
    )
    write_scene(qwen, "scene-0002", [make_frame(rng, "scene-0002", i) for i in range(3)], metadata=meta("qwen2.5-7b"))
    write_scene(qwen, "scene-0005", [make_frame(rng, "scene-0005", i) for i in range(12)], metadata=meta("qwen2.5-7b"))

    mine = root / "my-finetune"
    write_scene(mine, "scene-0001", [make_frame(rng, "scene-0001", i) for i in range(4)], metadata=meta("my-finetune"))
    return {
        "models": {"gpt-4o": gpt, "claude-3.7-sonnet": claude, "qwen-2.5-vl-7b": qwen, "my-finetune": mine},
        "frames": {"gpt-4o": 13, "claude-3.7-sonnet": 17, "qwen-2.5-vl-7b": 21, "my-finetune": 4},
        "bad_files": [gpt / "output" / "scene-0003.json"],
        "bad_frames": {"claude-3.7-sonnet": ["scene-0001.json frame 5", "scene-0004.json frame 7"]},
    }
