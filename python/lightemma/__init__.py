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
import importlib.abc
import importlib.util
import sys
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
    "simulate": "lightemma.planning.simulation",
    "comfort": "lightemma.planning.simulation",
    "drive_scores": "lightemma.planning.scores",
    "read_intents": "lightemma.explanations",
    "intent_consistency": "lightemma.explanations",
}

__all__ = sorted([*_EXPORTS, "__version__"])

# Modules that moved into lightemma.report (presentation) and lightemma.evaluation (what a report
# shows); their old import paths name the same module objects (never a second copy).
_MOVED: dict[str, str] = {
    "lightemma.figures": "lightemma.report.figures",
    "lightemma.pictures": "lightemma.report.pictures",
    "lightemma.tables": "lightemma.report.tables",
    "lightemma.evaluation.tables": "lightemma.report.evaluation_tables",
    "lightemma.scenarios": "lightemma.evaluation.scenarios",
    "lightemma.stats": "lightemma.evaluation.stats",
}


class _MovedModules(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Resolves an old module path (and its submodules) to the module at its new home."""

    @staticmethod
    def target(name: str) -> str | None:
        for old, new in _MOVED.items():
            if name == old or name.startswith(old + "."):
                return new + name[len(old):]
        return None

    def find_spec(self, name: str, path: Any = None, target: Any = None) -> Any:
        return importlib.util.spec_from_loader(name, self) if self.target(name) else None

    def create_module(self, spec: Any) -> Any:
        return importlib.import_module(self.target(spec.name))  # type: ignore[arg-type]

    def exec_module(self, module: Any) -> None:
        pass


if not any(isinstance(f, _MovedModules) for f in sys.meta_path):
    sys.meta_path.insert(0, _MovedModules())


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
    from lightemma.explanations import intent_consistency, read_intents
    from lightemma.frames import Frame, FrameSet, load_frames
    from lightemma.kinematics import integrate
    from lightemma.metrics import CONVENTIONS, Metrics, displacement_errors, evaluate, evaluate_all
    from lightemma.pipeline import RunResult, resume, run
    from lightemma.report import write_report
