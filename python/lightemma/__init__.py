"""lightemma: measure how well vision-language models drive.

The numeric and text kernels (parsing model answers, integrating actions into
trajectories, scoring them) live in the compiled, private module
``lightemma._core``; this package is the thin, documented public layer over it
plus data loading, prompting, backends, run storage, reporting and the CLI.

Attributes are imported lazily so that ``import lightemma`` stays fast and never
pulls in heavy dependencies (nuscenes-devkit, litellm, torch) until used.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"

# public name -> module that defines it
_EXPORTS: dict[str, str] = {
    "parse_actions": "lightemma.actions",
    "ParsedActions": "lightemma.actions",
    "integrate": "lightemma.kinematics",
    "displacement_errors": "lightemma.metrics",
    "evaluate": "lightemma.metrics",
    "evaluate_all": "lightemma.metrics",
    "Metrics": "lightemma.metrics",
    "CONVENTIONS": "lightemma.metrics",
    "load_frames": "lightemma.frames",
    "Frame": "lightemma.frames",
    "FrameSet": "lightemma.frames",
    "run": "lightemma.pipeline",
    "resume": "lightemma.pipeline",
    "RunResult": "lightemma.pipeline",
    "evaluate_runs": "lightemma.evaluation",
    "write_report": "lightemma.report",
    "run_demo": "lightemma.demo",
}

__all__ = sorted([*_EXPORTS, "__version__"])


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'lightemma' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return __all__


if TYPE_CHECKING:  # pragma: no cover - for type checkers and IDEs only
    from lightemma.actions import ParsedActions, parse_actions
    from lightemma.demo import run_demo
    from lightemma.evaluation import evaluate_runs
    from lightemma.frames import Frame, FrameSet, load_frames
    from lightemma.kinematics import integrate
    from lightemma.metrics import CONVENTIONS, Metrics, displacement_errors, evaluate, evaluate_all
    from lightemma.pipeline import RunResult, resume, run
    from lightemma.report import write_report
