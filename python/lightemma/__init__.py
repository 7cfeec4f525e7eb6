"""lightemma: measure how well vision-language models drive.

The numeric and text kernels (parsing model answers, integrating actions into
trajectories, scoring them) live in the compiled, private module
``lightemma._core``; this package is the thin, documented public layer over it
plus data loading, prompting, backends, run storage, reporting and the CLI.

Attributes are imported lazily so that ``import lightemma`` stays fast and never
pulls in heavy dependencies (litellm, torch) until used.
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
    "load_frames": "lightemma.nuscenes",
    "Frame": "lightemma.frames",
    "FrameSet": "lightemma.frames",
    "run": "lightemma.pipeline",
    "resume": "lightemma.pipeline",
    "RunResult": "lightemma.pipeline",
    "RunConfig": "lightemma.pipeline.config",
    "sweep": "lightemma.pipeline.variant_sweep",
    "evaluate_runs": "lightemma.evaluation",
    "write_report": "lightemma.report",
    "run_demo": "lightemma.offline_demo",
    "simulate": "lightemma.planning.simulation",
    "comfort": "lightemma.planning.simulation",
    "drive_scores": "lightemma.planning.scores",
    "read_intents": "lightemma.explanations",
    "intent_consistency": "lightemma.explanations",
    "read_objects": "lightemma.explanations",
    # lightemma's exceptions (lightemma.errors): the Rust core's errors arrive as these too
    "UserError": "lightemma.errors",
    "InputError": "lightemma.errors",
    "ShapeError": "lightemma.errors",
    "NonFiniteError": "lightemma.errors",
    "UnknownNameError": "lightemma.errors",
    "DatasetError": "lightemma.errors",
    "RunStoreError": "lightemma.errors",
    "RunFatalError": "lightemma.errors",
    "RunStopped": "lightemma.errors",
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
    # `X as X`: an explicit re-export (mypy's no_implicit_reexport; __all__ above is computed, so it cannot say)
    from lightemma.actions import ParsedActions as ParsedActions
    from lightemma.actions import parse_actions as parse_actions
    from lightemma.errors import DatasetError as DatasetError
    from lightemma.errors import InputError as InputError
    from lightemma.errors import NonFiniteError as NonFiniteError
    from lightemma.errors import RunFatalError as RunFatalError
    from lightemma.errors import RunStopped as RunStopped
    from lightemma.errors import RunStoreError as RunStoreError
    from lightemma.errors import ShapeError as ShapeError
    from lightemma.errors import UnknownNameError as UnknownNameError
    from lightemma.errors import UserError as UserError
    from lightemma.evaluation import evaluate_runs as evaluate_runs
    from lightemma.explanations import intent_consistency as intent_consistency
    from lightemma.explanations import read_intents as read_intents
    from lightemma.explanations import read_objects as read_objects
    from lightemma.frames import Frame as Frame
    from lightemma.frames import FrameSet as FrameSet
    from lightemma.kinematics import integrate as integrate
    from lightemma.metrics import CONVENTIONS as CONVENTIONS
    from lightemma.metrics import Metrics as Metrics
    from lightemma.metrics import displacement_errors as displacement_errors
    from lightemma.metrics import evaluate as evaluate
    from lightemma.metrics import evaluate_all as evaluate_all
    from lightemma.nuscenes import load_frames as load_frames
    from lightemma.offline_demo import run_demo as run_demo
    from lightemma.pipeline import RunResult as RunResult
    from lightemma.pipeline import resume as resume
    from lightemma.pipeline import run as run
    from lightemma.pipeline.config import RunConfig as RunConfig
    from lightemma.pipeline.variant_sweep import sweep as sweep
    from lightemma.planning.scores import drive_scores as drive_scores
    from lightemma.planning.simulation import comfort as comfort
    from lightemma.planning.simulation import simulate as simulate
    from lightemma.report import write_report as write_report
