"""The run pipeline: the per-frame chain, the concurrent runner, progress and summaries.

Public names: :func:`run`, :func:`resume`, :class:`RunResult`, :class:`RunConfig`, :func:`run_frame`,
:class:`ChainPolicy`, :func:`summarize`, :func:`format_summary`. Each is imported from its module when first used,
so that reading the run settings' table (:mod:`lightemma.pipeline.config`, which the CLI's parser reads) loads
neither the chain nor the backends.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

_EXPORTS = {
    "ChainPolicy": "chain",
    "run_frame": "chain",
    "RunResult": "runner",
    "resume": "runner",
    "run": "runner",
    "RunConfig": "config",
    "format_summary": "summary",
    "summarize": "summary",
}

__all__ = ["ChainPolicy", "RunConfig", "RunResult", "format_summary", "resume", "run", "run_frame", "summarize"]

if TYPE_CHECKING:
    from lightemma.pipeline.chain import ChainPolicy, run_frame
    from lightemma.pipeline.config import RunConfig
    from lightemma.pipeline.runner import RunResult, resume, run
    from lightemma.pipeline.summary import format_summary, summarize


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'lightemma.pipeline' has no attribute {name!r}")
    value = getattr(importlib.import_module(f"lightemma.pipeline.{module}"), name)
    globals()[name] = value
    return value
