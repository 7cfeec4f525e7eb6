"""The run pipeline: the per-frame chain, the concurrent runner, progress and summaries.

Public names: :func:`run`, :func:`resume`, :class:`RunResult`, :func:`run_frame`,
:class:`ChainPolicy`, :func:`summarize`, :func:`format_summary`.
"""

from lightemma.pipeline.chain import ChainPolicy, run_frame
from lightemma.pipeline.runner import RunResult, resume, run
from lightemma.pipeline.summary import format_summary, summarize

__all__ = ["ChainPolicy", "RunResult", "format_summary", "resume", "run", "run_frame", "summarize"]
