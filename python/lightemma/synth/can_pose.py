"""CAN-bus-like history of a synthetic scene: nuScenes' ``pose`` message (``can_bus/<scene>_pose.json``).

Messages every :data:`POSE_PERIOD_US` (50 Hz, as nuScenes' ``pose``) from the scene's first keyframe until the first
message at or after its last, in the devkit's format (``nuscenes/can_bus/can_bus_api.py``): ``utime`` (µs),
``pos`` [x, y, 0] (m, the global rear-axle position of ``ego_pose``), ``orientation`` (w, x, y, z) of the heading,
and in the ego frame ``vel`` [v, 0, 0] (m/s), ``accel`` [a, v²κ, 0] (m/s²: longitudinal, lateral; gravity is not
modelled, so z is 0, unlike the real IMU-based messages) and ``rotation_rate`` [0, 0, vκ] (rad/s) — the scene's
exact kinematics (speed v, acceleration a and curvature κ of :class:`~lightemma.synth.situations.Scenario`) at that
instant. ``vehicle_monitor`` and the other messages are not written.
"""

from __future__ import annotations

import math

import numpy as np

from lightemma.synth.situations import Scenario

#: spacing of the pose messages, µs (50 Hz)
POSE_PERIOD_US = 20_000


def pose_utimes(scn: Scenario) -> np.ndarray:
    """(M,) int64 message times: every :data:`POSE_PERIOD_US` from the first keyframe to the first at or after the
    last keyframe."""
    span = scn.keyframe_times_us[-1] - scn.start_us
    count = -(-span // POSE_PERIOD_US) + 1
    return scn.start_us + POSE_PERIOD_US * np.arange(count, dtype=np.int64)


def kinematics(scn: Scenario, utime) -> np.ndarray:
    """(M, 4) speed (m/s), longitudinal and lateral acceleration (m/s²), yaw rate (rad/s) at message time(s)
    ``utime`` (µs): v, a, v²κ, vκ of the scenario."""
    t = scn.seconds(utime)
    v = scn.speed(t)
    k = scn.curvature(t)
    return np.column_stack([v, scn.profile.a(t), v * v * k, v * k])


def pose_messages(scn: Scenario) -> list[dict]:
    """The scene's ``pose`` messages (a JSON-able list, the devkit's format)."""
    utimes = pose_utimes(scn)
    poses = scn.pose(scn.seconds(utimes))
    kin = kinematics(scn, utimes)
    out = []
    for u, (x, y, yaw), (v, a, a_lat, rate) in zip(utimes.tolist(), poses.tolist(), kin.tolist()):
        out.append(
            {
                "utime": int(u),
                "pos": [x, y, 0.0],
                "orientation": [math.cos(yaw / 2.0), 0.0, 0.0, math.sin(yaw / 2.0)],
                "vel": [v, 0.0, 0.0],
                "accel": [a, a_lat, 0.0],
                "rotation_rate": [0.0, 0.0, rate],
            }
        )
    return out
