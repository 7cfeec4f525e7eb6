"""Driving situations with known kinematics (the paper's failure cases among them).

Each :class:`Scenario` is fully determined by ``(index, seed, keyframes)``:
:func:`lightemma.synth.maps.build_scenarios` cycles through :data:`KINDS` and draws the free
parameters (speeds, accelerations, radii, timings, start pose) from a seeded
generator. Its ``pose(t)``, ``speed(t)`` and ``curvature(t)`` are exact and are
what the tables, the images and the tests are built from.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass, field

import numpy as np

from lightemma.errors import InputError
from lightemma.synth.motion import Path, SpeedProfile

#: scenario kinds, in the order scenes cycle through them
KINDS = (
    "cruise",
    "accelerate",
    "brake-red-light",
    "wait-then-go-green",
    "stopped-behind-lead-green",
    "left-turn",
    "right-turn",
    "straight-after-turn",
)

KEYFRAME_PERIOD_S = 0.5
SWEEPS_PER_KEYFRAME = 5  # CAM_FRONT records at 12 Hz: 5 sweeps between 2 Hz keyframes
KEYFRAME_JITTER_S = 0.02  # real keyframe spacing varies by a few ms to tens of ms
BASE_TIMESTAMP_US = 1_531_000_000_000_000
LANE_WIDTH = 3.5


@dataclass(frozen=True)
class Lead:
    """A lead vehicle on the ego's path, ``gap`` metres (centre to centre) ahead at t = 0."""

    gap: float
    profile: SpeedProfile
    length: float = 4.5
    width: float = 1.9
    height: float = 1.5
    color: tuple[int, int, int] = (40, 70, 140)


@dataclass(frozen=True)
class TrafficLight:
    """A signal at arc length ``stop_s`` on the path (stop line); ``schedule`` = ((t_from, colour), …)."""

    stop_s: float
    schedule: tuple[tuple[float, str], ...]
    crossing: float = 7.5  # metres from the stop line to the crossing road's centre line

    def colour(self, t: float) -> str:
        """Colour shown at time ``t`` (s): 'red', 'yellow' or 'green'."""
        current = self.schedule[0][1]
        for t_from, colour in self.schedule:
            if t >= t_from:
                current = colour
        return current


@dataclass(frozen=True)
class Scenario:
    """One synthetic scene: its name, closed-form ego motion, lead vehicle and light."""

    index: int
    kind: str
    description: str
    path: Path
    profile: SpeedProfile
    keyframe_times_us: tuple[int, ...]
    lead: Lead | None = None
    light: TrafficLight | None = None
    location: str = "boston-seaport"
    params: dict = field(default_factory=dict)

    @property
    def name(self) -> str:
        """Scene name, saying what happens: ``synth-0005-left-turn``."""
        return f"synth-{self.index:04d}-{self.kind}"

    @property
    def start_us(self) -> int:
        return self.keyframe_times_us[0]

    def seconds(self, timestamp_us) -> np.ndarray:
        """Scene time (s) of absolute timestamp(s) in µs."""
        return (np.asarray(timestamp_us, dtype=np.int64) - self.start_us) * 1e-6

    def pose(self, t) -> np.ndarray:
        """Global ego (x, y, yaw) at scene time(s) ``t`` (s): shape ``(..., 3)``."""
        return self.path.pose(self.profile.s(t))

    def speed(self, t) -> np.ndarray:
        """Ego speed (m/s) at scene time(s) ``t``."""
        return self.profile.v(t)

    def curvature(self, t) -> np.ndarray:
        """Ego path curvature (1/m, left positive) at scene time(s) ``t``."""
        return self.path.curvature(self.profile.s(t))

    def lead_pose(self, t) -> np.ndarray | None:
        """Global (x, y, yaw) of the lead vehicle at ``t``, or ``None`` without one."""
        if self.lead is None:
            return None
        return self.path.pose(self.profile.s(0.0) + self.lead.gap + self.lead.profile.s(t))

    def lead_speed(self, t) -> np.ndarray | None:
        """Lead vehicle speed at ``t``, or ``None``."""
        return None if self.lead is None else self.lead.profile.v(t)

    def light_colour(self, t: float) -> str | None:
        """Traffic light colour at ``t``, or ``None`` without a light."""
        return None if self.light is None else self.light.colour(float(t))

    @property
    def duration(self) -> float:
        return (self.keyframe_times_us[-1] - self.start_us) * 1e-6


def _rng(seed: int, index: int) -> np.random.Generator:
    digest = hashlib.sha256(f"lightemma-synth/{seed}/{index}".encode()).digest()
    return np.random.default_rng(int.from_bytes(digest[:8], "little"))


def _keyframe_times(rng: np.random.Generator, index: int, seed: int, keyframes: int) -> tuple[int, ...]:
    start = BASE_TIMESTAMP_US + (seed % 1000) * 86_400_000_000 + index * 60_000_000
    jitter = rng.uniform(-KEYFRAME_JITTER_S, KEYFRAME_JITTER_S, size=keyframes)
    jitter[0] = 0.0
    secs = np.arange(keyframes) * KEYFRAME_PERIOD_S + jitter
    return tuple(int(start + round(s * 1e6)) for s in secs)


def _cap(v0: float, accel: float, vmax: float) -> tuple[float, float]:
    """Phase accelerating from v0 at ``accel`` until exactly ``vmax``."""
    return ((vmax - v0) / accel, accel)


def build_scenario(index: int, *, seed: int = 0, keyframes: int = 40) -> Scenario:
    """The scenario of scene ``index`` (kind ``KINDS[index % 8]``) for ``seed``."""
    if keyframes < 2:
        raise InputError(f"a scene needs at least 2 keyframes, got {keyframes}")
    rng = _rng(seed, index)
    kind = KINDS[index % len(KINDS)]
    times = _keyframe_times(rng, index, seed, keyframes)
    duration = (times[-1] - times[0]) * 1e-6
    x0, y0 = rng.uniform(200.0, 1800.0, size=2)
    yaw0 = float(rng.uniform(-math.pi, math.pi))
    location = ("boston-seaport", "singapore-onenorth")[int(rng.integers(2))]
    lead = light = None
    segments: tuple[tuple[float, float], ...] = ((1000.0, 0.0),)
    p: dict = {}

    if kind == "cruise":
        v = float(rng.uniform(7.0, 12.0))
        profile = SpeedProfile(v)
        lead = Lead(gap=float(rng.uniform(18.0, 28.0)), profile=SpeedProfile(v))
        p = {"speed": v, "lead_gap": lead.gap}
        desc = f"Cruising at {v:.1f} m/s behind a vehicle moving at the same speed"
    elif kind == "accelerate":
        v0 = float(rng.uniform(1.0, 3.0))
        a = float(rng.uniform(0.8, 1.5))
        vmax = float(rng.uniform(10.0, 13.0))
        profile = SpeedProfile(v0, (_cap(v0, a, vmax),))
        light = TrafficLight(stop_s=float(profile.s(duration) + 30.0), schedule=((0.0, "green"),))
        p = {"v0": v0, "accel": a, "vmax": vmax}
        desc = f"Accelerating from {v0:.1f} to {vmax:.1f} m/s at {a:.2f} m/s² towards a green light"
    elif kind == "brake-red-light":
        v0 = float(rng.uniform(8.0, 11.0))
        t_brake = float(rng.uniform(0.3, 0.4)) * duration
        t_stop = float(rng.uniform(0.65, 0.75)) * duration  # at rest for the last quarter or so
        decel = v0 / (t_stop - t_brake)
        profile = SpeedProfile(v0, ((t_brake, 0.0), (t_stop - t_brake, -decel)))
        stop_s = float(profile.s(duration)) + 2.0
        light = TrafficLight(stop_s=stop_s, schedule=((0.0, "yellow"), (max(0.0, t_brake - 1.5), "red")))
        p = {"v0": v0, "decel": decel, "t_brake": t_brake, "t_stop": t_stop}
        desc = f"Braking from {v0:.1f} m/s at {decel:.2f} m/s² to stop at a red light"
    elif kind == "wait-then-go-green":
        t_green = float(rng.uniform(0.4, 0.5)) * duration
        react = float(rng.uniform(0.5, 1.5))
        a = float(rng.uniform(1.2, 2.0))
        vmax = float(rng.uniform(8.0, 11.0))
        profile = SpeedProfile(0.0, ((t_green + react, 0.0), _cap(0.0, a, vmax)))
        light = TrafficLight(stop_s=2.0, schedule=((0.0, "red"), (t_green, "green")))
        p = {"t_green": t_green, "reaction": react, "accel": a, "vmax": vmax}
        desc = f"Waiting at a red light; it turns green at {t_green:.1f} s and the car pulls away at {a:.2f} m/s²"
    elif kind == "stopped-behind-lead-green":
        t_green = float(rng.uniform(0.3, 0.4)) * duration
        gap = float(rng.uniform(7.0, 9.0))
        lead_delay, ego_delay = 1.0, float(rng.uniform(2.0, 3.0))
        a_lead, a_ego = 1.6, float(rng.uniform(1.0, 1.4))
        lead = Lead(gap=gap, profile=SpeedProfile(0.0, ((t_green + lead_delay, 0.0), _cap(0.0, a_lead, 10.0))))
        profile = SpeedProfile(0.0, ((t_green + ego_delay, 0.0), _cap(0.0, a_ego, 9.0)))
        light = TrafficLight(stop_s=gap + 3.0, schedule=((0.0, "red"), (t_green, "green")))
        p = {"t_green": t_green, "gap": gap, "ego_delay": ego_delay, "accel": a_ego}
        desc = f"Stopped behind a vehicle at a red light; green at {t_green:.1f} s, both pull away"
    elif kind in ("left-turn", "right-turn"):
        v = float(rng.uniform(5.0, 7.0))
        radius = float(rng.uniform(12.0, 18.0) if kind == "left-turn" else rng.uniform(9.0, 14.0))
        sign = 1.0 if kind == "left-turn" else -1.0
        approach = v * float(rng.uniform(0.3, 0.45)) * duration
        profile = SpeedProfile(v)
        segments = ((approach, 0.0), (math.pi / 2 * radius, sign / radius), (1000.0, 0.0))
        # the crossing road is the one turned into: its centre line is the exit straight
        light = TrafficLight(stop_s=approach - 4.0, schedule=((0.0, "green"),), crossing=4.0 + radius)
        p = {"speed": v, "radius": radius, "approach": approach}
        side = "left" if sign > 0 else "right"
        desc = f"Turning {side} at a green light at {v:.1f} m/s on a {radius:.1f} m radius"
    elif kind == "straight-after-turn":
        v = float(rng.uniform(5.0, 7.0))
        sign = 1.0 if rng.integers(2) == 0 else -1.0
        radius = float(rng.uniform(10.0, 14.0))
        approach = v * 1.0
        profile = SpeedProfile(v)
        segments = ((approach, 0.0), (math.pi / 2 * radius, sign / radius), (1000.0, 0.0))
        p = {"speed": v, "radius": radius, "turn": "left" if sign > 0 else "right"}
        desc = f"Driving straight right after a {p['turn']} turn ({radius:.1f} m radius) at {v:.1f} m/s"
    else:  # pragma: no cover - KINDS is closed
        raise AssertionError(kind)

    return Scenario(
        index=index,
        kind=kind,
        description=desc,
        path=Path(float(x0), float(y0), yaw0, segments),
        profile=profile,
        keyframe_times_us=times,
        lead=lead,
        light=light,
        location=location,
        params=p,
    )


def sweep_times_us(keyframe_times_us: tuple[int, ...]) -> list[list[int]]:
    """Timestamps of the CAM_FRONT sweeps between consecutive keyframes (12 Hz)."""
    out = []
    for a, b in zip(keyframe_times_us[:-1], keyframe_times_us[1:]):
        n = SWEEPS_PER_KEYFRAME + 1
        out.append([a + round((b - a) * j / n) for j in range(1, n)])
    return out
