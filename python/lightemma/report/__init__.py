"""Present what :mod:`lightemma.evaluation` computes: the report folder (``lightemma report``),
table formatting (:mod:`~lightemma.report.tables`), the paper's tables of an evaluation
(:mod:`~lightemma.report.evaluation_tables`), figures (:mod:`~lightemma.report.figures`) and
the cameras and stage texts of frame pictures (:mod:`~lightemma.report.pictures`).

Names are imported lazily: ``lightemma.evaluation`` re-exports the table builders, and the
writer imports ``lightemma.evaluation`` — neither import may run the other's body first.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

_EXPORTS: dict[str, str] = {
    "write_report": "lightemma.report.writer",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'lightemma.report' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


if TYPE_CHECKING:  # pragma: no cover
    from lightemma.report.writer import write_report
