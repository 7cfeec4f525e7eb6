"""A synthetic nuScenes-format dataset with known kinematics, for offline use.

:func:`write_dataset` writes scenes (cruising, accelerating, braking at a red
light, waiting then going at green, stopped behind a lead vehicle at green,
left and right turns, straight right after a turn) that the unmodified
``nuscenes-devkit`` loads. :func:`build_scenarios` gives the closed-form truth
(``Scenario.pose(t)``, ``.speed(t)``, ``.curvature(t)``) they are made from.
"""

from __future__ import annotations

from lightemma.synth.camera import Camera
from lightemma.synth.dataset import build_tables, write_dataset
from lightemma.synth.drawing import render_frame
from lightemma.synth.maps import build_scenarios
from lightemma.synth.motion import Path, SpeedProfile
from lightemma.synth.situations import KINDS, Scenario, build_scenario, sweep_times_us

__all__ = [
    "KINDS",
    "Camera",
    "Path",
    "Scenario",
    "SpeedProfile",
    "build_scenario",
    "build_scenarios",
    "build_tables",
    "render_frame",
    "sweep_times_us",
    "write_dataset",
]
