"""Re-simulation and comfort kernels (rust/planning/simulate.rs, comfort.rs) against an independent NumPy oracle.

The oracle below follows NAVSIM's definitions step by step, batched as NAVSIM batches them (pseudo-inverse least
squares of ``batch_lqr_utils.py``, the LQR of ``batch_lqr.py``, the bicycle of ``batch_kinematic_bicycle.py``, the
filters of ``pdm_comfort_metrics.py`` through SciPy's ``savgol_filter``); it shares no code with the kernels.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import savgol_filter

import lightemma
from lightemma import _core
from lightemma.planning import simulation as sim

# ---------------------------------------------------------------- the oracle: NAVSIM's simulation in NumPy

X, Y, H, VX, VY, AX, AY, STEER, STEER_RATE, YAW_RATE, YAW_ACC = range(11)


def _norm(a):
    return np.arctan2(np.sin(a), np.cos(a))


def oracle_resample(poses, initial, plan_dt, dt):
    k = poses.shape[1]
    knots_t = np.arange(k + 1) * plan_dt
    knots = np.concatenate([initial[:, None, :3], poses], axis=1)
    knots[..., 2] = np.unwrap(knots[..., 2], axis=1)
    steps = round(k * plan_dt / dt)
    times = np.arange(steps + 1) * dt
    # np.interp on every frame and column, vectorised: knots are evenly spaced
    index = np.minimum(np.searchsorted(knots_t, times, side="right") - 1, k - 1)
    fraction = ((times - knots_t[index]) / plan_dt)[None, :, None]
    return knots[:, index] + (knots[:, index + 1] - knots[:, index]) * fraction


def oracle_profiles(poses, dt, jerk_penalty=1e-4, curvature_rate_penalty=1e-2):
    b = poses.shape[0]
    diff = np.diff(poses, axis=1)
    xy, dh = diff[..., :2], _norm(diff[..., 2])
    m = xy.shape[1]
    # velocity and acceleration: displacement_i = dt (cos, sin)(h_i) (v0 + dt Σ_{j<i} a_j)
    y = xy.reshape(b, -1)
    col = np.zeros_like(y)
    col[:, 0::2] = np.cos(poses[:, :-1, 2])
    col[:, 1::2] = np.sin(poses[:, :-1, 2])
    a = np.repeat(col[..., None] * dt**2, m, axis=2)
    a[..., 0] = col * dt
    a[:, np.repeat(np.triu(np.ones((m, m), bool), k=1), 2, axis=0)] = 0.0
    band = np.zeros((m - 2, m - 1))
    band[:, 1:] += np.eye(m - 2)
    band[:, :-1] -= np.eye(m - 2)
    r = np.block([np.zeros((m - 2, 1)), band])
    at = a.transpose(0, 2, 1)
    x = np.einsum("bij,bj->bi", np.linalg.pinv(at @ a + jerk_penalty * (r.T @ r)) @ at, y)
    v = x[:, :1] + np.pad(np.cumsum(x[:, 1:] * dt, axis=1), [(0, 0), (1, 0)])
    # curvature and curvature rate: heading displacement_i = v_i dt (κ0 + dt Σ_{j<i} κ'_j)
    ak = np.repeat(np.tri(m)[None], b, axis=0)
    ak[:, :, 0] = v * dt
    ak[:, 1:, 1:] *= (v * dt**2)[:, 1:, None]
    q = curvature_rate_penalty * np.eye(m)
    q[0, 0] = 1e-10
    akt = ak.transpose(0, 2, 1)
    kx = np.einsum("bij,bj->bi", np.linalg.pinv(akt @ ak + q) @ akt, dh)
    kappa = kx[:, :1] + np.pad(np.cumsum(kx[:, 1:] * dt, axis=1), [(0, 0), (1, 0)])
    return v, kappa


def oracle_simulate(poses, initial, vehicle, plan_dt=0.5, dt=0.1, horizon=10):
    ref = oracle_resample(poses, initial, plan_dt, dt)
    v_prof, k_prof = oracle_profiles(ref, dt)
    n, steps = ref.shape[0], ref.shape[1] - 1
    wb = vehicle.wheel_base
    out = np.zeros((n, steps + 1, 11))
    out[:, 0] = initial
    q_lat = np.diag([1.0, 10.0, 0.0])
    for i in range(steps):
        s = out[:, i]
        dx, dy, rh = s[:, X] - ref[:, i, 0], s[:, Y] - ref[:, i, 1], ref[:, i, 2]
        lat = np.stack([-dx * np.sin(rh) + dy * np.cos(rh), _norm(s[:, H] - rh), s[:, STEER]], axis=-1)
        ridx = min(i + horizon, v_prof.shape[1] - 1)
        vref = v_prof[:, ridx]
        kref = np.zeros((n, horizon))
        length = ridx - i
        kref[:, :length] = k_prof[:, i:ridx]
        kref[:, length:] = k_prof[:, ridx, None]
        v0 = s[:, VX]
        stop = (vref <= 0.2) & (v0 <= 0.2)
        bl = horizon * dt
        accel = -(bl * 10.0 * (v0 - vref)) / (bl * 10.0 * bl + 1.0)
        vel = v0[:, None] + accel[:, None] * dt * np.arange(horizon)
        am = np.tile(np.eye(3), (n, 1, 1))
        bm = np.zeros((n, 3, 1))
        gm = np.zeros((n, 3))
        for step in range(horizon):
            mk = np.tile(np.eye(3), (n, 1, 1))
            mk[:, 0, 1] = vel[:, step] * dt
            mk[:, 1, 2] = vel[:, step] * dt / wb
            aff = np.zeros((n, 3))
            aff[:, 1] = -vel[:, step] * kref[:, step] * dt
            am = mk @ am
            bm = mk @ bm + np.array([[0.0], [0.0], [dt]])
            gm = np.einsum("bij,bj->bi", mk, gm) + aff
        e = np.einsum("bij,bj->bi", am, lat) + gm
        e[:, 1:] = _norm(e[:, 1:])
        btq = bm.transpose(0, 2, 1) @ q_lat
        rate = -(np.einsum("bij,bj->bi", btq, e) / (np.einsum("bij,bji->bi", btq, bm) + 1.0))[:, 0]
        accel = np.where(stop, -0.5 * (v0 - vref), accel)
        rate = np.where(stop, 0.0, rate)
        # bicycle: lagged commands, Euler step about the rear axle
        new_a = dt / (dt + vehicle.accel_time_constant) * (accel - s[:, AX]) + s[:, AX]
        ideal = dt * rate + s[:, STEER]
        new_steer = dt / (dt + vehicle.steering_angle_time_constant) * (ideal - s[:, STEER]) + s[:, STEER]
        new_rate = (new_steer - s[:, STEER]) / dt
        nxt = out[:, i + 1]
        nxt[:, X] = s[:, X] + s[:, VX] * np.cos(s[:, H]) * dt
        nxt[:, Y] = s[:, Y] + s[:, VX] * np.sin(s[:, H]) * dt
        heading = s[:, H] + s[:, VX] * np.tan(s[:, STEER]) / wb * dt
        nxt[:, H] = (heading + np.pi) % (2 * np.pi) - np.pi
        nxt[:, VX] = s[:, VX] + new_a * dt
        nxt[:, STEER] = np.clip(s[:, STEER] + new_rate * dt, -vehicle.max_steering_angle, vehicle.max_steering_angle)
        nxt[:, YAW_RATE] = nxt[:, VX] * np.tan(nxt[:, STEER]) / wb
        nxt[:, AX] = new_a
        nxt[:, YAW_ACC] = (nxt[:, YAW_RATE] - s[:, YAW_RATE]) / dt
        nxt[:, STEER_RATE] = new_rate
    return out


# ---------------------------------------------------------------- the oracle: NAVSIM's comfort in NumPy/SciPy


def _unwrap(h):
    adj = np.zeros_like(h)
    adj[..., 1:] = np.cumsum(np.round(np.diff(h, axis=-1) / (2 * np.pi)), axis=-1)
    return h - 2 * np.pi * adj


def _deriv(y, t, window, order, deriv):
    window = min(window, len(t))
    return savgol_filter(y, polyorder=order, window_length=window, deriv=deriv, delta=np.diff(t).mean(), axis=-1)


def _accel(a, n):
    return np.round(savgol_filter(a, polyorder=2, window_length=min(8, n), axis=-1), 8)


def oracle_signals(states, dt, r):
    n = states.shape[1]
    t = np.arange(n) * dt
    lon = _accel(states[..., AX] + r * states[..., YAW_RATE] ** 2 + r * states[..., YAW_ACC], n)
    lat = _accel(states[..., AY], n)
    mag = _accel(np.hypot(states[..., AX], states[..., AY]), n)
    jerk = np.round(_deriv(mag, t, 15, 2, 1), 8)
    lon_jerk = np.round(_deriv(lon, t, 15, 2, 1), 8)
    head = _unwrap(states[..., H])
    yaw_acc = np.round(_deriv(head, t, 5, 3, 2), 8)  # NAVSIM's window 15 never reaches the filter: 5
    yaw_rate = np.round(_deriv(head, t, 5, 2, 1), 8)
    return [lon, lat, jerk, lon_jerk, yaw_acc, yaw_rate]


LIMITS = [(-4.05, 2.40), (-4.89, 4.89), (-8.37, 8.37), (-4.13, 4.13), (-1.93, 1.93), (-0.95, 0.95)]


def oracle_comfort(states, dt=0.1, r=sim.ZOE.rear_axle_to_center):
    signals = oracle_signals(states, dt, r)
    within = np.stack([((s > lo) & (s < hi)).all(axis=-1) for s, (lo, hi) in zip(signals, LIMITS)], axis=1)
    extremes = np.stack([np.stack([s.min(axis=-1), s.max(axis=-1)], axis=-1) for s in signals], axis=1)
    return within, extremes


def oracle_extended(now, prev, dt=0.1, shift=5):
    a, b = now[:, :-shift], prev[:, shift:]
    n = a.shape[1]
    t = np.arange(n) * dt

    def features(s):
        mag = _accel(np.hypot(s[..., AX], s[..., AY]), n)
        head = _unwrap(s[..., H])
        return [
            mag,
            np.round(_deriv(mag, t, 15, 2, 1), 8),
            np.round(_deriv(head, t, 5, 2, 1), 8),
            np.round(_deriv(head, t, 5, 2, 2), 8),  # extract_features: default order 2
        ]

    return np.stack([np.sqrt(np.mean((fa - fb) ** 2, axis=1)) for fa, fb in zip(features(a), features(b))], axis=1)


# ---------------------------------------------------------------- cases


def random_plans(rng, n, k=6, plan_dt=0.5):
    """Plausible plans: speeds 0–20 m/s with changes, curvatures up to ±0.08 1/m, and matching initial states."""
    speeds = np.clip(rng.uniform(0, 18, (n, 1)) + np.cumsum(rng.normal(0, 1.0, (n, k)), axis=1), 0, None)
    curv = rng.normal(0, 0.03, (n, 1)) + np.cumsum(rng.normal(0, 0.01, (n, k)), axis=1)
    poses = sim.plan_poses(np.stack([speeds, curv], axis=-1), dt=plan_dt)
    init = np.zeros((n, 11))
    init[:, VX] = np.clip(speeds[:, 0] + rng.normal(0, 0.5, n), 0, None)
    init[:, AX] = rng.normal(0, 0.5, n)
    init[:, AY] = rng.normal(0, 0.3, n)
    init[:, STEER] = rng.normal(0, 0.02, n)
    init[:, YAW_RATE] = init[:, VX] * np.tan(init[:, STEER]) / sim.ZOE.wheel_base
    return poses, init


def test_simulate_matches_the_numpy_oracle_on_random_plans():
    rng = np.random.default_rng(7)
    poses, init = random_plans(rng, 300)
    # a few stopping and start-up plans, and global-frame headings across ±π
    poses[:10] = 0.0
    init[:5, VX] = 0.1
    init[10:20, H] = np.pi - 0.05
    poses[10:20, :, 2] += np.pi - 0.05
    for vehicle in (sim.ZOE, sim.PACIFICA):
        got = lightemma.simulate(poses, init, vehicle=vehicle)
        want = oracle_simulate(poses, init, vehicle)
        assert got.shape == (300, 31, 11)
        diff = np.abs(got - want)
        diff[..., H] = np.abs(_norm(got[..., H] - want[..., H]))
        assert diff.max() < 1e-6, np.unravel_index(diff.argmax(), diff.shape)


def test_large_batches_match_frame_by_frame():
    # 2,100 frames: the GIL-free path and several parallel tasks; every frame as if simulated alone
    rng = np.random.default_rng(2)
    poses, init = random_plans(rng, 2100)
    states = lightemma.simulate(poses, init)
    for i in (0, 63, 64, 255, 256, 2099):
        np.testing.assert_array_equal(states[i : i + 1], lightemma.simulate(poses[i : i + 1], init[i : i + 1]))
    c = sim.comfort_details(states)
    e = sim.extended_comfort_details(states[1:], states[:-1])
    for i in (0, 255, 256, 2098):
        np.testing.assert_array_equal(c.extremes[i : i + 1], sim.comfort_details(states[i : i + 1]).extremes)
        np.testing.assert_array_equal(
            e.rms[i], sim.extended_comfort_details(states[i + 1 : i + 2], states[i : i + 1]).rms[0]
        )


def test_simulate_hand_made_cases():
    # straight at constant speed: tracked exactly
    poses = np.stack([np.arange(1, 7) * 5.0, np.zeros(6), np.zeros(6)], axis=-1)[None]
    init = np.zeros((1, 11))
    init[0, VX] = 10.0
    out = lightemma.simulate(poses, init)
    np.testing.assert_allclose(out[0, :, X], np.arange(31) * 1.0, atol=1e-9)
    np.testing.assert_allclose(out[0, :, VX], 10.0, atol=1e-9)
    assert np.abs(out[0, :, [Y, H, STEER, AX]]).max() < 1e-9
    # a plan that speeds up: the simulated car speeds up, lagging the reference
    fast = np.stack(
        [10 * np.arange(1, 7) * 0.5 + 0.5 * 2.0 * (np.arange(1, 7) * 0.5) ** 2, np.zeros(6), np.zeros(6)], -1
    )
    out = lightemma.simulate(fast[None], init)
    assert out[0, -1, VX] > 13.0 and (np.diff(out[0, :, VX]) >= -1e-12).all()
    np.testing.assert_allclose(out, oracle_simulate(fast[None], init, sim.ZOE), atol=1e-8)


def test_comfort_matches_the_numpy_oracle():
    rng = np.random.default_rng(11)
    poses, init = random_plans(rng, 200)
    states = lightemma.simulate(poses, init)
    # noisy states too: every bound is crossed by some frames
    noisy = states + rng.normal(0, 1, states.shape) * np.array([0, 0, 0.02, 0.1, 0, 0.5, 0.8, 0, 0, 0.05, 0.3])
    both = np.concatenate([states, noisy])
    for r in (sim.ZOE.rear_axle_to_center, sim.PACIFICA.rear_axle_to_center):
        vehicle = sim.Vehicle(wheel_base=2.588, rear_axle_to_center=r)
        got = sim.comfort_details(both, vehicle=vehicle)
        within, extremes = oracle_comfort(both, r=r)
        np.testing.assert_allclose(got.extremes, extremes, atol=1e-7)
        np.testing.assert_array_equal(got.within, within)
        np.testing.assert_array_equal(lightemma.comfort(both, vehicle=vehicle), within.all(axis=1).astype(float))
    assert 0 < within.all(axis=1).mean() < 1
    assert within.all(axis=0).sum() < 6, "the noisy frames must cross some bounds"


@pytest.mark.parametrize("n", [4, 5, 8, 9, 15, 16, 45])
def test_comfort_filters_on_short_and_long_horizons(n):
    rng = np.random.default_rng(n)
    states = rng.normal(0, 1, (20, n, 11))
    got = sim.comfort_details(states, dt=0.1)
    within, extremes = oracle_comfort(states)
    np.testing.assert_allclose(got.extremes, extremes, atol=1e-7)
    np.testing.assert_array_equal(got.within, within)


def test_history_comfort_is_comfort_of_the_padded_sequence():
    rng = np.random.default_rng(3)
    poses, init = random_plans(rng, 50)
    states = lightemma.simulate(poses, init)
    history = np.stack([np.arange(-7, 1) * 4.0 + rng.normal(0, 0.05, (50, 8)), rng.normal(0, 0.05, (50, 8))], -1)
    history[:, -1] = 0.0
    past = sim.history_states(history)
    assert past.states.shape == (50, 14, 11) and all(r is None for r in past.reasons)
    got = sim.history_comfort(past.states, states)
    within, _ = oracle_comfort(np.concatenate([past.states, states], axis=1))
    np.testing.assert_array_equal(got.within, within)


def test_extended_comfort_matches_the_numpy_oracle():
    rng = np.random.default_rng(5)
    poses, init = random_plans(rng, 200)
    now = lightemma.simulate(poses, init)
    prev = lightemma.simulate(poses + rng.normal(0, 0.3, poses.shape) * [1, 1, 0.02], init)
    got = sim.extended_comfort_details(now, prev)
    want = oracle_extended(now, prev)
    np.testing.assert_allclose(got.rms, want, atol=1e-7)
    np.testing.assert_array_equal(got.comfortable, (want <= [0.7, 0.5, 0.1, 0.1]).all(axis=1).astype(float))
    assert 0 < got.comfortable.mean() < 1
    # nuScenes keyframes are about 0.5 s apart: NAVSIM rounds the spacing to whole steps
    np.testing.assert_array_equal(sim.extended_comfort_details(now, prev, interval=0.47).rms, got.rms)
    np.testing.assert_allclose(
        sim.extended_comfort_details(now, prev, interval=0.41).rms, oracle_extended(now, prev, shift=4), atol=1e-7
    )
    # the same plan, seen 0.5 s later: the shifted states agree → comfortable
    same = sim.extended_comfort(now, now)
    assert np.isfinite(same).all()


def test_initial_state_from_history():
    # constant acceleration 1 m/s² at 5 m/s now, along x: v = 5, a = 1, no yaw
    t = np.arange(-7, 1) * 0.5
    hist = np.stack([5 * t + 0.5 * t**2, np.zeros(8)], -1)[None]
    got = sim.initial_state(hist)
    assert got.reasons == [None]
    np.testing.assert_allclose(got.states[0, [VX, AX, YAW_RATE, STEER]], [5.0, 1.0, 0.0, 0.0], atol=1e-12)
    # on a circle of radius 25 m at 10 m/s: yaw rate 0.4 rad/s, steering atan(L / R); the three-point formulas
    # over 1 s of 2 Hz positions (0.2 rad per keyframe) are within 5 % of them
    r, v = 25.0, 10.0
    ang = v * t / r
    circle = np.stack([r * np.sin(ang), r * (1 - np.cos(ang))], -1)[None]
    s = sim.initial_state(circle).states[0]
    assert abs(s[YAW_RATE] / (v / r) - 1) < 0.05
    assert abs(np.tan(s[STEER]) / (sim.ZOE.wheel_base / r) - 1) < 0.05
    assert abs(s[VX] / v - 1) < 0.05 and abs(s[AY] / (v**2 / r) - 1) < 0.05


def test_initial_state_from_the_can_bus():
    t = np.arange(-7, 1) * 0.5
    hist = np.tile(np.stack([6 * t, np.zeros(8)], -1), (3, 1, 1))
    can = np.array([[6.3, -1.2, 0.4, 0.05], [np.nan, 0.0, 0.0, 0.0], [10.0, 0.0, 0.0, 0.0]])
    got = sim.initial_state(hist, can=can)
    # row 0: the readings, steering from the yaw rate; row 1: no reading, the positions' values
    np.testing.assert_allclose(got.states[0, [VX, AX, AY, YAW_RATE]], [6.3, -1.2, 0.4, 0.05])
    assert abs(got.states[0, STEER] - np.arctan(sim.ZOE.wheel_base * 0.05 / 6.3)) < 1e-12
    np.testing.assert_allclose(got.states[1, [VX, AX, YAW_RATE]], [6.0, 0.0, 0.0], atol=1e-12)
    # row 2: 10 m/s on the CAN bus but 6 m/s from the positions: not available, both named
    assert got.reasons[:2] == [None, None] and "10.00" in got.reasons[2] and "6.00" in got.reasons[2]
    assert np.isnan(got.states[2]).all()
    with pytest.raises(ValueError, match="can has 2 rows"):
        sim.initial_state(hist, can=can[:2])


def test_bad_input_is_not_available_with_a_reason():
    hist = np.zeros((3, 8, 2))
    hist[:, :, 0] = np.arange(-7, 1) * 2.0
    hist[1, -2, 0] = np.nan
    hist[2, -1] = [0.5, 0.0]
    got = sim.initial_state(hist)
    assert got.reasons[0] is None
    assert "NaN" in got.reasons[1] and "frame 1" in got.reasons[1]
    assert "origin" in got.reasons[2]
    assert np.isnan(got.states[1:]).all() and np.isfinite(got.states[0]).all()
    np.testing.assert_array_equal(got.available, [True, False, False])
    # a plan with NaN or inf, or an underivable initial state: that frame's states are NaN, comfort NaN, not 0 or 1
    poses = np.tile(np.stack([np.arange(1, 7) * 1.0, np.zeros(6), np.zeros(6)], -1), (3, 1, 1))
    poses[0, 3, 1] = np.inf
    states = lightemma.simulate(poses, got.states)
    assert np.isnan(states[0]).all() and np.isnan(states[1:]).all()
    assert np.isnan(lightemma.comfort(states)).all()
    assert np.isnan(sim.extended_comfort(states, states)).all()
    # a history that could not be derived makes history comfort not available, not a score
    start = np.zeros((1, 11))
    start[0, VX] = 2.0
    good = lightemma.simulate(poses[1:2], start)
    hist = np.zeros((2, 8, 2))
    hist[:, :, 0] = np.arange(-7, 1) * 1.0
    hist[1, -3, 1] = np.nan
    past = sim.history_states(hist)
    assert past.reasons[0] is None and "frame 1" in past.reasons[1]
    hc = sim.history_comfort(past.states, np.concatenate([good, good])).comfortable
    assert hc[0] in (0.0, 1.0) and np.isnan(hc[1])


@pytest.fixture(scope="module")
def uneven(tmp_path_factory):
    """A synthetic dataset (keyframes 0.46–0.53 s apart, as nuScenes') with its scenarios' exact kinematics."""
    from lightemma.nuscenes import load_frames
    from lightemma.synth import build_scenarios, write_dataset

    scenes, keyframes = 3, 20  # cruise, accelerate, brake at a red light
    root = write_dataset(
        tmp_path_factory.mktemp("uneven"), scenes=scenes, keyframes=keyframes, images=False, sweeps=False
    )
    by_name = {s.name: s for s in build_scenarios(scenes, keyframes=keyframes)}
    frames = load_frames(root, "v1.0-mini", on_missing_image="keep")
    # the history keyframes' timestamps (s), oldest first, as the frames' history_positions
    times = (
        np.array(
            [
                np.asarray(by_name[n].keyframe_times_us)[k - 7 : k + 1]
                for n, k in zip(frames.scene_names, frames.keyframe_indices)
            ]
        )
        / 1e6
    )
    return root, by_name, frames, times


def _constant_acceleration_rows(by_name, frames, times):
    """Frames moving straight (> 1 m/s) with one acceleration over their last three keyframes: there the quadratic
    through the three positions is the motion itself, so the derived speed and acceleration are exact."""
    from lightemma.synth import can_pose as synth_can

    rows = []
    for i, (name, t) in enumerate(zip(frames.scene_names, times)):
        kin = synth_can.kinematics(by_name[name], np.round(t[-3:] * 1e6).astype(np.int64))
        if (kin[:, 0] > 1.0).all() and np.ptp(kin[:, 1]) < 1e-12 and not kin[:, 2:].any():
            rows.append(i)
    return np.array(rows)


def test_initial_state_uses_the_real_keyframe_spacing(uneven):
    from lightemma.nuscenes import can_bus

    root, by_name, frames, times = uneven
    spacing = np.diff(times[:, -3:], axis=1)
    assert np.abs(spacing - sim.STEP_SECONDS).max() > 0.02  # the spacing is uneven, as in nuScenes
    rows = _constant_acceleration_rows(by_name, frames, times)
    assert len(rows) >= 6 and {frames.scene_names[i] for i in rows} >= {"synth-0000-cruise", "synth-0001-accelerate"}
    can = can_bus.frame_can_readings(frames)
    assert can is not None and can.available[rows].all()
    got = sim.initial_state(frames.history_positions[rows], times=times[rows])
    assert got.reasons == [None] * len(rows)
    # the CAN reading is the 50 Hz message nearest the keyframe (≤ 10 ms away: |Δv| ≤ 3.2 m/s² · 0.01 s); its
    # accelerations are exact on these frames (up to the timestamps' whole microseconds: 1e-4 m/s²)
    np.testing.assert_allclose(got.states[:, VX], can.values[rows, 0], rtol=0, atol=0.035)
    np.testing.assert_allclose(got.states[:, [AX, AY]], can.values[rows, 1:3], rtol=0, atol=1e-4)
    # the 0.5 s assumption is off on the same frames (by up to ~0.9 m/s and ~2 m/s²)
    assumed = sim.initial_state(frames.history_positions[rows]).states
    assert np.abs(assumed[:, VX] - can.values[rows, 0]).max() > 0.2
    assert np.abs(assumed[:, AX] - can.values[rows, 1]).max() > 0.5
    # even spacing given as times is the default
    even = np.tile(np.arange(-7, 1) * sim.STEP_SECONDS + 3.0, (len(rows), 1))
    np.testing.assert_allclose(
        sim.initial_state(frames.history_positions[rows], times=even).states, assumed, rtol=0, atol=1e-9
    )
    np.testing.assert_allclose(
        sim.history_states(frames.history_positions[rows], times=even).states,
        sim.history_states(frames.history_positions[rows]).states,
        rtol=0,
        atol=1e-9,
    )


def test_history_states_use_the_real_keyframe_spacing(uneven):
    root, by_name, frames, times = uneven
    rows = np.array([i for i, n in enumerate(frames.scene_names) if n == "synth-0001-accelerate"])
    # the accelerating scene keeps one acceleration over its whole history: every keyframe state is exact, and the
    # linear interpolation between them is exact for the speed (linear in time)
    from lightemma.synth import can_pose as synth_can

    past = sim.history_states(frames.history_positions[rows], times=times[rows])
    assert past.reasons == [None] * len(rows)
    instants = np.arange(-sim.HISTORY_SECONDS, 0.0, 0.1)[:-1]
    for j, i in enumerate(rows):
        scn = by_name[frames.scene_names[i]]
        start = times[i, -4:]
        assert (np.diff(times[i, -5:]) > 0).all()
        when = np.round((times[i, -1] + instants) * 1e6).astype(np.int64)
        kin = synth_can.kinematics(scn, when)
        inside = instants >= start[0] - times[i, -1]  # an instant before the oldest keyframe is extrapolated
        np.testing.assert_allclose(past.states[j, inside, VX], kin[inside, 0], rtol=0, atol=1e-4)
        np.testing.assert_allclose(past.states[j, :, AX], kin[:, 1], rtol=0, atol=1e-4)


def test_the_planning_score_takes_the_keyframe_timestamps(uneven, tmp_path):
    """The caller passes each history keyframe's timestamp: without a CAN bus the initial speed is the exact one."""
    import shutil

    from lightemma.evaluation import planning_score as P
    from lightemma.evaluation import safety as S
    from lightemma.synth import can_pose as synth_can

    root, by_name, frames, times = uneven
    data_root = tmp_path / "data"
    shutil.copytree(root, data_root, ignore=shutil.ignore_patterns("can_bus"))
    rows = _constant_acceleration_rows(by_name, frames, times)
    tokens = [frames.sample_tokens[i] for i in rows]
    data = S.load_safety_data(data_root, "v1.0-mini", samples=set(tokens), history=P.HISTORY_KEYFRAMES)
    got = P._frames(data, tokens, [frames.scene_names[i] for i in rows])
    ok = np.array([r is None for r in got.reason])
    assert ok.sum() >= 4
    truth = np.array(
        [synth_can.kinematics(by_name[frames.scene_names[i]], [int(frames.timestamps[i])])[0] for i in rows]
    )
    # exact up to the timestamps' whole microseconds (1e-4)
    np.testing.assert_allclose(got.init[ok, VX], truth[ok, 0], rtol=0, atol=1e-4)
    np.testing.assert_allclose(got.init[ok, AX], truth[ok, 1], rtol=0, atol=1e-4)


def test_times_that_cannot_be_used():
    hist = np.zeros((3, 8, 2))
    hist[:, :, 0] = np.arange(-7, 1) * 2.0
    times = np.tile(np.arange(-7, 1) * 0.5, (3, 1))
    times[1, -2] = np.nan
    times[2, -2] = times[2, -1]
    got = sim.initial_state(hist, times=times)
    assert got.reasons[0] is None and "frame 1" in got.reasons[1] and "times" in got.reasons[1]
    assert "not increasing" in got.reasons[2] and np.isnan(got.states[1:]).all()
    past = sim.history_states(hist, times=times)
    assert past.reasons[0] is None and "not increasing" in past.reasons[2] and np.isnan(past.states[1:]).all()
    with pytest.raises(ValueError, match=r"times must have shape \(3, 8\)"):
        sim.initial_state(hist, times=times[:, 1:])
    with pytest.raises(ValueError, match="dt must be a positive"):
        sim.history_states(hist, dt=0.0)


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda: lightemma.simulate(np.zeros((2, 6, 2)), np.zeros((2, 11))), "poses must have shape"),
        (lambda: lightemma.simulate(np.zeros((2, 6, 3)), np.zeros((3, 11))), "initial_state has 3 rows"),
        (lambda: lightemma.simulate(np.zeros((2, 6, 3)), np.zeros((2, 11)), dt=0.07), "whole number"),
        (lambda: lightemma.simulate([["a"]], np.zeros((1, 11))), "real numbers"),
        (
            lambda: lightemma.simulate(np.zeros((1, 6, 3)), np.zeros((1, 11)), vehicle=sim.Vehicle(0.0, 1.0)),
            "wheel_base",
        ),
        (lambda: lightemma.comfort(np.zeros((2, 3, 11))), "at least 4 states"),
        (lambda: lightemma.comfort(np.zeros((2, 31, 10))), "states must have shape"),
        (lambda: lightemma.comfort(np.zeros((2, 31, 11)), dt=0.0), "dt must be"),
        (lambda: sim.extended_comfort(np.zeros((2, 31, 11)), np.zeros((2, 30, 11))), "shape of states_now"),
        (lambda: sim.extended_comfort(np.zeros((2, 31, 11)), np.zeros((2, 31, 11)), interval=0.6), "0.55"),
        (lambda: sim.extended_comfort(np.zeros((2, 31, 11)), np.zeros((2, 31, 11)), interval=0.04), "half a step"),
        (lambda: sim.initial_state(np.zeros((2, 2, 2))), "at least 3 positions"),
        (lambda: sim.history_comfort(np.zeros((3, 14, 11)), np.zeros((2, 31, 11))), "history has 3 frames"),
        (lambda: sim.history_comfort(np.zeros((2, 14, 10)), np.zeros((2, 31, 11))), "history must have shape"),
    ],
)
def test_bad_arguments_raise_one_line(call, message):
    with pytest.raises(ValueError, match=message) as info:
        call()
    assert "\n" not in str(info.value)


def test_public_names_and_constants():
    assert lightemma.simulate is sim.simulate and lightemma.comfort is sim.comfort
    assert sim.COMFORT_BOUNDS == (
        "lon_acceleration",
        "lat_acceleration",
        "jerk",
        "lon_jerk",
        "yaw_acceleration",
        "yaw_rate",
    )
    assert sim.COMFORT_LIMITS == tuple(LIMITS)
    assert sim.EXTENDED_COMFORT_LIMITS == (0.7, 0.5, 0.1, 0.1)
    assert _core.simulate.__doc__
