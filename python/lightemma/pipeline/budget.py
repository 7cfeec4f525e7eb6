"""A run's spending limit (``max_cost_cents``, ``--max-cost``): what each call is admitted at, and the session's
:class:`~lightemma.pipeline.estimate.Budget` (the run's recorded spending counted in).

The runner's guard reserves a frame's calls against the budget before it starts them (:mod:`lightemma.pipeline.runner`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from lightemma.backends import Backend
from lightemma.errors import UserError
from lightemma.models.catalog import resolve
from lightemma.pipeline.config import RunConfig
from lightemma.pipeline.estimate import Budget, estimate
from lightemma.prompts import PromptSet
from lightemma.runs.store import read_run


def session_budget(
    run_dir: Path,
    config: RunConfig,
    todo: Sequence[Any],
    backend: Backend,
    prompts: PromptSet,
    *,
    resuming: bool = False,
) -> Any:
    """The session's ``--max-cost`` budget (None without one): the run's recorded spending, what each call is
    admitted at (:func:`admitted_cents_per_call`)."""
    limit = config.max_cost_cents
    if limit is None:
        return None

    per_call = admitted_cents_per_call(config, todo, backend, prompts, resuming=resuming)
    spent = sum(float(r.get("cost_cents") or 0.0) for r in read_run(run_dir).records.values())
    return Budget(float(limit), per_call, spent, chain_calls=Budget.CHAIN_CALLS * config.prompting.samples)


def check_admits_a_frame(config: RunConfig, frames: Sequence[Any], backend: Backend, prompts: PromptSet) -> None:
    """A new run's limit that bounds nothing or admits no frame: a one-line :class:`UserError` before anything
    exists (nothing without a limit)."""
    limit = config.max_cost_cents
    if limit is None:
        return

    per_call = admitted_cents_per_call(config, frames, backend, prompts)
    calls = Budget.CHAIN_CALLS * config.prompting.samples  # a frame's K chains (--samples K)
    if limit < calls * per_call:
        frame = calls * per_call
        what = "three calls" if calls == Budget.CHAIN_CALLS else f"{calls} calls ({config.prompting.samples} samples)"
        raise UserError(
            f"--max-cost {limit:g}: not one frame fits within it (a frame is admitted at "
            f"{frame:.3f} ¢, its {what} at {per_call:.3f} ¢ each); give at least --max-cost "
            f"{math.ceil(frame * 1000) / 1000:g}, or drop it"
        )


def admitted_cents_per_call(
    config: RunConfig, todo: Sequence[Any], backend: Backend, prompts: PromptSet, *, resuming: bool = False
) -> float:
    """The cents ``--max-cost`` admits each call of ``todo`` at (the estimate per call, or its upper bound where the
    model's image tokens are unknown: :meth:`~lightemma.pipeline.estimate.Estimate.admitted_cents_per_call`); a
    one-line :class:`UserError` where no spending can be bounded. Reads and writes nothing: a new run checks it before
    its run directory exists."""
    info = resolve(config.model)
    price = list(config.api.price) if config.api.price is not None else None
    planned = estimate(
        todo,
        info,
        backend.provider,
        prompts,
        max_tokens=config.prompting.max_tokens,
        chain=config.prompting.chain,
        inputs=config.prompting.inputs,
        given_price=price,
        served_from=backend.api_base_shown if backend.served_elsewhere else None,
    )
    batch = bool(config.batch.enabled)
    per_call = planned.admitted_cents_per_call(batch)
    if per_call is not None:
        return per_call
    bound = planned.batch_bound if batch else planned.bound
    if bound is None or bound.unknown == "price":
        fix = (
            "a resume keeps the run's price (it has none): drop --max-cost, or start a new run with --price IN OUT"
            if resuming
            else "give it with --price IN OUT, or drop --max-cost"
        )
        raise UserError(
            f"--max-cost: the price of {config.model} is unknown ({planned.price_source}), so no spending "
            f"can be bounded; {fix}"
        )
    raise UserError(
        f"--max-cost: the image tokens of {config.model} are unknown (no published image rule) and "
        f"{bound.source}, so no spending can be bounded: drop --max-cost (--estimate shows what is known)"
    )
