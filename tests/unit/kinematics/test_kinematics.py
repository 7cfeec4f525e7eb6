"""Integration of actions: agreement with a NumPy reference, closed forms, bad input."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

import lightemma


def reference_integrate(actions: np.ndarray, dt: float, method: str) -> np.ndarray:
    """A plain NumPy transcription of docs/definitions.md#integration, vectorised over frames."""
    n, t, _ = actions.shape
    out = np.zeros((n, t, 2))
    x = np.zeros(n)
    y = np.zeros(n)
    heading = np.zeros(n)
    for k in range(t):
        v, kappa = actions[:, k, 0], actions[:, k, 1]
        turn = kappa * v * dt
        direction = heading if method == "euler" else heading + turn / 2
        x = x + v * np.cos(direction) * dt
        y = y + v * np.sin(direction) * dt
        heading = heading + turn
        out[:, k, 0], out[:, k, 1] = x, y
    return out


actions_strategy = hnp.arrays(
    np.float64,
    st.tuples(st.integers(1, 20), st.integers(1, 8), st.just(2)),
    elements=st.floats(-30, 30, allow_nan=False, allow_infinity=False),
)


@settings(max_examples=200, deadline=None)
@given(actions_strategy, st.sampled_from(["euler", "midpoint"]), st.sampled_from([0.1, 0.5, 1.0]))
def test_matches_numpy_reference(actions, method, dt):
    got = lightemma.integrate(actions, dt=dt, method=method)
    np.testing.assert_allclose(got, reference_integrate(actions, dt, method), rtol=1e-12, atol=1e-9)


def test_single_frame_in_single_frame_out():
    actions = np.array([[2.0, 0.0]] * 6)
    out = lightemma.integrate(actions)
    assert out.shape == (6, 2)
    np.testing.assert_allclose(out[:, 0], np.arange(1, 7) * 1.0)


def test_straight_line_closed_form():
    v = np.linspace(1, 12, 6)
    actions = np.stack([v, np.zeros(6)], axis=-1)
    for method in ("euler", "midpoint"):
        out = lightemma.integrate(actions, method=method)
        np.testing.assert_allclose(out[:, 0], np.cumsum(v * 0.5))
        np.testing.assert_array_equal(out[:, 1], 0.0)


def arc(v: float, radius: float, steps: int = 6, dt: float = 0.5) -> np.ndarray:
    angle = v * dt * np.arange(1, steps + 1) / radius
    return np.stack([radius * np.sin(angle), radius * (1 - np.cos(angle))], axis=-1)


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_constant_radius_arc(sign):
    v, radius = 5.0, 100.0
    actions = np.tile([v, sign / radius], (6, 1))
    truth = arc(v, radius) * [1.0, sign]
    midpoint = np.linalg.norm(lightemma.integrate(actions, method="midpoint")[-1] - truth[-1])
    euler = np.linalg.norm(lightemma.integrate(actions, method="euler")[-1] - truth[-1])
    assert midpoint < 1e-3
    assert euler > 0.1  # Euler's bias: it turns one step late
    # Euler lags on the inside of the turn: its lateral offset is smaller than the truth
    assert abs(lightemma.integrate(actions)[-1, 1]) < abs(truth[-1, 1])


def test_euler_bias_is_about_a_metre_at_8_ms_on_50_m():
    actions = np.tile([8.0, 1 / 50.0], (6, 1))
    truth = arc(8.0, 50.0)
    bias = np.linalg.norm(lightemma.integrate(actions)[-1] - truth[-1])
    assert 0.7 < bias < 1.1


def test_nan_actions_give_nan_positions_without_touching_others():
    actions = np.tile([3.0, 0.0], (2, 6, 1))
    actions[1, 2, 0] = np.nan
    out = lightemma.integrate(actions)
    assert np.isfinite(out[0]).all()
    assert np.isfinite(out[1, :2]).all() and np.isnan(out[1, 2:]).all()


def test_accepts_lists_ints_and_non_contiguous_views():
    as_ints = lightemma.integrate([[[2, 0], [2, 0]]])
    np.testing.assert_allclose(as_ints, [[[1.0, 0.0], [2.0, 0.0]]])
    wide = np.tile([[2.0, 0.0, 9.0, 9.0]], (3, 1))[None]  # (1, 3, 4)
    view = wide[:, :, :2]
    assert not view.flags["C_CONTIGUOUS"]
    np.testing.assert_allclose(lightemma.integrate(view)[0, :, 0], [1.0, 2.0, 3.0])


def test_large_batch_runs_without_the_gil_and_agrees():
    rng = np.random.default_rng(0)
    actions = np.stack([rng.uniform(0, 15, (5000, 6)), rng.uniform(-0.1, 0.1, (5000, 6))], axis=-1)
    np.testing.assert_allclose(lightemma.integrate(actions), reference_integrate(actions, 0.5, "euler"), atol=1e-9)


@pytest.mark.parametrize(
    ("actions", "kwargs", "message"),
    [
        (np.zeros((2, 6, 3)), {}, r"shape \(N, T, 2\) or \(T, 2\), got \(2, 6, 3\)"),
        (np.zeros(6), {}, r"got \(6,\)"),
        (np.zeros((1, 1, 6, 2)), {}, r"got \(1, 1, 6, 2\)"),
        (np.array([["a", "b"]]), {}, "must hold numbers, got dtype <U1"),
        ([[1, 2], [3]], {}, "cannot be turned into an array"),
        (np.zeros((1, 6, 2)), {"method": "rk4"}, 'unknown integration method "rk4"; expected one of: euler, midpoint'),
        (np.zeros((1, 6, 2)), {"dt": 0.0}, "dt must be a positive finite number"),
        (np.zeros((1, 6, 2)), {"dt": float("nan")}, "dt must be a positive finite number"),
        (np.zeros((1, 0, 2)), {}, r"at least one step"),
        (np.zeros((2, 6, 2), dtype=complex), {}, "real numbers"),
    ],
)
def test_bad_input_is_a_value_error(actions, kwargs, message):
    with pytest.raises(ValueError, match=message):
        lightemma.integrate(actions, **kwargs)


def test_empty_batch_is_empty():
    assert lightemma.integrate(np.zeros((0, 6, 2))).shape == (0, 6, 2)


@pytest.mark.parametrize("method", ["euler", "midpoint"])
def test_lockstep_batches_equal_single_frames_bit_for_bit(method):
    # 8 frames go through the interleaved (lockstep, AVX2 where present) path; a lone frame does not
    rng = np.random.default_rng(3)
    actions = np.stack([rng.uniform(0, 20, (19, 6)), rng.uniform(-0.3, 0.3, (19, 6))], axis=-1)
    actions[4, 2, 1] = 1e6  # an out-of-range heading in one lane takes the libm fix-up
    batch = lightemma.integrate(actions, method=method)
    for i, frame in enumerate(actions):
        np.testing.assert_array_equal(batch[i], lightemma.integrate(frame, method=method))


def test_bool_actions_are_refused_with_their_dtype():
    with pytest.raises(ValueError, match=r"actions must hold numbers, got dtype bool \(shape \(6, 2\)\)"):
        lightemma.integrate(np.ones((6, 2), dtype=bool))
    with pytest.raises(ValueError, match="got dtype bool"):
        lightemma.integrate([[[True, False]] * 6])


def test_integrate_writes_into_out_when_given():
    rng = np.random.default_rng(3)
    actions = np.stack([rng.uniform(0, 15, (5000, 6)), rng.normal(0, 0.05, (5000, 6))], axis=2)
    out = np.full_like(actions, 7.0)  # whatever was there is overwritten
    got = lightemma.integrate(actions, method="midpoint", out=out)
    assert got is out
    np.testing.assert_array_equal(out, lightemma.integrate(actions, method="midpoint"))
    with pytest.raises(ValueError, match="shape"):
        lightemma.integrate(actions, out=np.empty((4999, 6, 2)))
    with pytest.raises(ValueError, match="share memory"):
        lightemma.integrate(actions, out=actions)
    with pytest.raises(ValueError, match="float64"):
        lightemma.integrate(actions, out=np.empty((5000, 6, 2), dtype=np.float32))
    with pytest.raises(ValueError, match="C-contiguous"):
        lightemma.integrate(actions, out=np.empty((5000, 6, 4))[..., ::2])
