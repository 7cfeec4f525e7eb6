"""Baselines as backends: answers in the strict format, the right actions, the oracle's floor."""

from __future__ import annotations

import asyncio
from types import SimpleNamespace

import numpy as np
import pytest

import lightemma
from lightemma.backends.base import Backend, ChatRequest
from lightemma.backends.baseline import BaselineBackend, format_actions

HISTORY = np.array([[5.0, 0.0], [5.5, 0.01], [6.0, 0.02], [6.5, 0.015], [7.0, -0.0], [7.25, -0.0123]])


def arc_frame(speed: float = 8.0, radius: float = 50.0) -> SimpleNamespace:
    """A frame driving a circle of ``radius`` at ``speed``: exact GT positions, GT actions."""
    t = np.arange(1, 7) * 0.5
    angle = speed * t / radius
    gt_positions = np.stack([radius * np.sin(angle), radius * (1 - np.cos(angle))], axis=1)
    gt_actions = np.array([[speed, 1.0 / radius]] * 6)
    return SimpleNamespace(history_actions=HISTORY, gt_actions=gt_actions, gt_positions=gt_positions)


def ask(backend: BaselineBackend, frame, stages=("scene", "intent", "actions")):
    requests = [ChatRequest(text="prompt", stage=s, frame_id="f", frame=frame) for s in stages]
    return asyncio.run(backend.generate(requests))


@pytest.mark.parametrize(
    ("kind", "expected"),
    [
        ("constant", np.repeat(HISTORY[-1:], 6, axis=0)),
        ("cv", np.array([[7.25, 0.0]] * 6)),
        ("oracle", np.array([[8.0, 0.02]] * 6)),
    ],
)
def test_answers_parse_strictly_to_the_baseline_actions(kind, expected):
    backend = BaselineBackend(kind)
    assert isinstance(backend, Backend)
    scene, intent, answer = ask(backend, arc_frame())
    assert scene.ok and intent.ok and scene.text.startswith("baseline")
    parsed = lightemma.parse_actions([answer.text], mode="strict")
    assert list(parsed.status) == ["ok"]
    np.testing.assert_allclose(parsed.actions[0], expected, atol=1e-6)
    for result in (scene, intent, answer):
        assert result.input_tokens == 0 and result.output_tokens == 0 and result.cost_cents == 0.0
    assert backend.info["backend"] == "baseline" and backend.info["kind"] == kind
    assert backend.name == f"baseline:{kind}"


def test_number_format_is_plain():
    text = format_actions(np.array([[-0.0, -1e-9], [3.0, 0.1234567], [12.5, -0.02]] + [[1, 0]] * 3))
    assert text.startswith("[(0.0, 0.0), (3.0, 0.123457), (12.5, -0.02), (1.0, 0.0)")
    assert "e" not in text and "np." not in text and "-0.0," not in text


def test_oracle_shows_the_integrators_error_floor():
    """GT actions integrated: Euler is biased on an arc (≈0.9 m at 3 s, docs/definitions.md#integration), midpoint is not."""
    frame = arc_frame()
    (answer,) = ask(BaselineBackend("oracle"), frame, stages=("actions",))
    actions = lightemma.parse_actions([answer.text], mode="strict").actions
    euler = lightemma.integrate(actions, method="euler")[0]
    midpoint = lightemma.integrate(actions, method="midpoint")[0]
    euler_fde = np.linalg.norm(euler[-1] - frame.gt_positions[-1])
    midpoint_fde = np.linalg.norm(midpoint[-1] - frame.gt_positions[-1])
    assert 0.6 < euler_fde < 1.2
    assert midpoint_fde < 0.05


def test_frame_as_mapping_and_errors_are_results_not_exceptions():
    mapping = {"history_actions": HISTORY.tolist(), "gt_actions": None}
    (ok,) = ask(BaselineBackend("cv"), mapping, stages=("actions",))
    assert ok.ok
    (missing,) = ask(BaselineBackend("oracle"), mapping, stages=("actions",))
    assert not missing.ok and missing.text is None and "gt_actions" in missing.error_message
    (no_frame,) = ask(BaselineBackend("constant"), None, stages=("actions",))
    assert no_frame.error == "ValueError"
    with pytest.raises(ValueError, match="unknown baseline"):
        BaselineBackend("magic")


def test_baselines_on_frames_of_a_synthetic_dataset(tmp_path):
    """Frame objects from load_frames: the oracle answers the frame's own gt_actions."""
    from lightemma.synth import write_dataset

    root = write_dataset(tmp_path, scenes=8, keyframes=16, image_size=(160, 90), sweeps=False)
    frames = list(lightemma.load_frames(root, "v1.0-mini", split="all"))
    for kind, field in (("oracle", "gt_actions"), ("constant", "history_actions")):
        results = asyncio.run(
            BaselineBackend(kind).generate(
                [ChatRequest(text="", stage="actions", frame_id=f.frame_id, frame=f) for f in frames]
            )
        )
        parsed = lightemma.parse_actions([r.text for r in results], mode="strict")
        assert set(parsed.status) == {"ok"}
        expected = np.stack([getattr(f, field) for f in frames])
        if kind == "constant":
            expected = np.repeat(expected[:, -1:], 6, axis=1)
        np.testing.assert_allclose(parsed.actions, expected, atol=1e-6)
