"""Run summaries: statuses, format-error rates, ADE, time, tokens, cost, throughput.

Definitions: docs/definitions.md#format-errors and #efficiency.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np

from lightemma.backends.base import is_truncated
from lightemma.metrics import evaluate
from lightemma.runs.records import answer_received, first_answer_status


def _mean(values: list[float]) -> float | None:
    return float(np.mean(values)) if values else None


def summarize(
    records: Iterable[Mapping[str, Any]], *, wall_seconds: float | None = None, frames_run: int | None = None
) -> dict[str, Any]:
    """Aggregate run records (one per frame, the final one) into a summary dict.

    ``wall_seconds`` and ``frames_run`` describe this session (frames actually
    run now, not those found done by a resume) and give frames per second.
    """
    records = list(records)
    n = len(records)
    statuses = {s: sum(1 for r in records if r.get("status") == s) for s in ("ok", "corrected", "failed")}
    # FE is over frames whose stage-3 answer was received; frames whose calls all failed at the provider are apart
    received = [first_answer_status(r) for r in records if answer_received(r)]
    # frames without any stage-3 answer: lost to API errors, or every attempt cut off before stage 3
    unanswered = [r for r in records if not answer_received(r)]
    api_error_frames = sum(1 for r in unanswered if r.get("failure", "api_error") == "api_error")
    first_not_ok = sum(1 for first in received if first != "ok")
    first_failed = sum(1 for first in received if first == "failed")
    m = len(received)
    costs = [r.get("cost_cents") for r in records]
    known_costs = [c for c in costs if c is not None]
    valid = [r for r in records if r.get("trajectory") is not None and r.get("gt_positions") is not None]
    ade = None
    if valid:
        pred = np.asarray([r["trajectory"] for r in valid], dtype=np.float64)
        gt = np.asarray([r["gt_positions"] for r in valid], dtype=np.float64)
        ade = float(evaluate(pred, gt).ade_avg)
    summary: dict[str, Any] = {
        "frames": n,
        **statuses,
        "fe_percent": 100.0 * first_not_ok / m if m else None,
        "fe_corr_percent": 100.0 * first_failed / m if m else None,
        "answered_frames": m,
        "api_error_frames": api_error_frames,
        "cut_off_frames": len(unanswered) - api_error_frames,
        "ade_avg": ade,
        "ade_frames": len(valid),
        "mean_seconds_per_frame": _mean([r["seconds"] for r in records if r.get("seconds") is not None]),
        "mean_input_tokens": _mean([r["input_tokens"] for r in records if r.get("input_tokens") is not None]),
        "mean_output_tokens": _mean([r["output_tokens"] for r in records if r.get("output_tokens") is not None]),
        "total_cost_cents": sum(known_costs) if known_costs else None,
        "mean_cost_cents": _mean(known_costs),
        "frames_cost_unknown": n - len(known_costs),
        "attempts": sum(r.get("n_attempts", len(r.get("attempts", []))) for r in records),
        "api_errors": sum(
            1 for r in records for a in r.get("attempts", []) for c in a.get("calls", []) if c.get("error")
        ),
        "cached_calls": sum(r.get("cached_calls", 0) for r in records),
        # unknown stays unknown: frames whose tokens a provider did not (fully) report are left out of the means
        "frames_tokens_unknown": sum(
            1 for r in records if r.get("input_tokens") is None or r.get("output_tokens") is None
        ),
        "mean_reasoning_tokens": _mean(
            [r["reasoning_tokens"] for r in records if r.get("reasoning_tokens") is not None]
        ),
        "cached_input_percent": _cached_percent(records),
        "truncated_calls": sum(
            1
            for r in records
            for a in r.get("attempts", [])
            for c in a.get("calls", [])
            if is_truncated(c.get("finish_reason"))
        ),
        "top_failure": _top_failure(records),
    }
    if wall_seconds is not None:
        summary["wall_seconds"] = wall_seconds
        summary["frames_run"] = frames_run
        summary["frames_per_second"] = (frames_run / wall_seconds) if frames_run and wall_seconds > 0 else None
    return summary


def _cached_percent(records: list[Mapping[str, Any]]) -> float | None:
    """100 × Σ cached input tokens ÷ Σ input tokens over the frames reporting both (None when none does)."""
    both = [
        (r["cached_input_tokens"], r["input_tokens"])
        for r in records
        if r.get("cached_input_tokens") is not None and r.get("input_tokens")
    ]
    return 100.0 * sum(c for c, _ in both) / sum(t for _, t in both) if both else None


def _top_failure(records: list[Mapping[str, Any]]) -> str | None:
    """The most common reason the last attempt of a failed frame gives (None when no frame failed)."""
    reasons = Counter(
        str((r.get("attempts") or [{}])[-1].get("reason") or r.get("error") or "unknown")
        for r in records
        if r.get("status") == "failed"
    )
    return reasons.most_common(1)[0][0] if reasons else None


def _fmt(value: Any, spec: str, unit: str = "") -> str:
    return "n/a" if value is None else f"{value:{spec}}{unit}"


def format_summary(summary: Mapping[str, Any], *, title: str = "") -> str:
    """A few aligned lines for the terminal."""
    lines = [title] if title else []
    lines += [
        f"frames        {summary['frames']}  (ok {summary['ok']}, corrected {summary['corrected']}, failed {summary['failed']})",
        f"FE            {_fmt(summary['fe_percent'], '.2f', ' %')}   FE corr {_fmt(summary['fe_corr_percent'], '.2f', ' %')}"
        + _unanswered(summary),
        f"ADE avg       {_fmt(summary['ade_avg'], '.3f', ' m')}  over {summary['ade_frames']} frame(s)",
        (
            f"time/frame    n/a (batch mode; mean batch turnaround {_fmt(summary.get('batch_turnaround_s'), '.0f', ' s')})"
            if summary.get("batch")
            else f"time/frame    {_fmt(summary['mean_seconds_per_frame'], '.2f', ' s')}"
        ),
        f"tokens/frame  in {_fmt(summary['mean_input_tokens'], '.0f')}, out {_fmt(summary['mean_output_tokens'], '.0f')}"
        + (
            f" (of which reasoning {_fmt(summary['mean_reasoning_tokens'], '.0f')})"
            if summary.get("mean_reasoning_tokens")
            else ""
        )
        + (
            f", {summary['cached_input_percent']:.1f} % of input from the prompt cache"
            if summary.get("cached_input_percent")
            else ""
        )
        + (f"  ({summary['frames_tokens_unknown']} unknown)" if summary.get("frames_tokens_unknown") else ""),
        f"cost          {_fmt(summary['total_cost_cents'], '.2f', ' ¢')} total, {_fmt(summary['mean_cost_cents'], '.3f', ' ¢')}/frame"
        + (f"  ({summary['frames_cost_unknown']} frame(s) unpriced)" if summary["frames_cost_unknown"] else ""),
        f"calls         {summary['attempts']} attempt(s), {summary['api_errors']} API error(s), {summary['cached_calls']} cached"
        + (f", {summary['truncated_calls']} truncated" if summary.get("truncated_calls") else ""),
    ]
    if "wall_seconds" in summary:
        lines.append(
            f"wall time     {summary['wall_seconds']:.1f} s for {summary['frames_run']} frame(s), "
            f"{_fmt(summary['frames_per_second'], '.2f', ' frames/s')}"
        )
    return "\n".join(lines)


def _unanswered(summary: Mapping[str, Any]) -> str:
    """Why FE is over fewer frames than the run has: frames that received no stage-3 answer, by cause."""
    api, cut = summary.get("api_error_frames") or 0, summary.get("cut_off_frames") or 0
    causes = [*([f"API errors only: {api}"] if api else []), *([f"cut off before stage 3: {cut}"] if cut else [])]
    return f"  (over {summary['answered_frames']} answered frame(s); {'; '.join(causes)})" if causes else ""
