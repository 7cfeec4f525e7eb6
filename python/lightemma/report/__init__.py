"""Present what :mod:`lightemma.evaluation` computes: the report folder (``lightemma report``),
table formatting (:mod:`~lightemma.report.tables`), the paper's tables of an evaluation
(:mod:`~lightemma.report.evaluation_tables`), figures (:mod:`~lightemma.report.figures`) and
the cameras and stage texts of frame pictures (:mod:`~lightemma.report.pictures`).

Names are imported lazily, so that importing one of its modules (the table formatting the CLI's
``evaluate`` uses) does not import the report writer and everything it builds on.
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
    from lightemma.report.writer import write_report as write_report  # an explicit re-export
