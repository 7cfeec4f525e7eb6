"""The three-stage chain for one frame, written once for every backend.

scene description → driving intent → actions (docs/definitions.md#the-three-stages), each one call with the
frame's image; each stage's text is pasted into the next. The stage-3 answer is
parsed by the Rust core in lenient mode (``ok`` / ``corrected`` / ``failed``).
A failed answer — or a call that failed with an API error after the backend's
retries — is re-asked: stage 3 alone (``reask="actions"``, the default; an
earlier stage that failed is redone first) or the whole chain
(``reask="chain"``), up to ``max_attempts`` attempts in all.

An API error is never model text: a failed call ends its attempt with the
error class recorded, and only texts of successful calls reach a prompt.
A text cut off at the output-token limit (``finish_reason`` length) is recorded
but never passed on: a truncated scene or intent ends its attempt like a failed
call (and is asked again), a truncated answer is ``failed`` with reason
"truncated" (``failure: "truncated"`` on the attempt), unparsed.
Every call's tokens, time and cost count toward the frame (docs/definitions.md#format-errors, #efficiency); a
total is null when any of its calls did not report it.

Two request variants (:class:`ChainPolicy`): ``answer_format="structured"`` asks
stage 3 for the JSON object ``{"actions": [[v, c] × 6]}`` through the backend's
constrained decoding and parses it with ``mode="json"`` (plausibility still
applies); ``chain="conversation"`` sends stages 2 and 3 as one conversation
continued (the image once, in the first user turn; the earlier stages' prompts
and answers as turns). A stage-3 re-ask in a conversation resends the same
conversation up to the stage-3 prompt — the failed answer is not shown to the
model — exactly as an independent re-ask resends the same request.

An input ablation (``ChainPolicy.inputs``, :mod:`lightemma.inputs`) changes what every stage is shown:
no image, a blank one of the frame's size, or (through the prompt set's no-history variant, chosen by
the runner) no history numbers.

K samples (``ChainPolicy.samples`` > 1, ``--samples K``; docs/run.md#k-samples): K independent chains per frame,
each asked and re-asked as above with its sample index on every request. A fresh frame's first stage-1 request
is drawn for every sample at once (:meth:`~lightemma.backends.base.Backend.generate_samples`: one request with
``n`` where the backend supports it, else K requests). Sample 0's record is the frame record as without sampling;
samples 1..K-1 are in its ``samples`` list; the frame's token, time and cost totals count every sample's calls.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, cast

import numpy as np

from lightemma.actions import history_rows, parse_actions, plausibility
from lightemma.backends.base import Backend, ChatRequest, ChatResult, GenerationParams, ResponseSchema, is_truncated
from lightemma.backends.structured import ACTIONS_SCHEMA
from lightemma.definitions import INTEGRATION_METHODS, STEP_SECONDS
from lightemma.errors import InputError
from lightemma.frames import history_placeholders
from lightemma.inputs import check_inputs, describe_perturbation, request_image, shown_history
from lightemma.kinematics import integrate
from lightemma.prompts import ANSWER_FORMATS, CHAINS, PromptSet
from lightemma.runs.records import attempt_received
from lightemma.runs.schema import AttemptRecord, CallRecord, FrameRecord, attempt_record, call_record, frame_record

REASK_MODES = ("actions", "chain")


@dataclass(frozen=True)
class ChainPolicy:
    """How a frame is asked and re-asked; recorded in the run manifest.

    ``speed_range`` (m/s) and ``max_abs_curvature`` (1/m) are the parser's
    plausibility limits (None disables one); see :func:`lightemma.parse_actions`.
    """

    params: GenerationParams = field(default_factory=GenerationParams)
    reask: str = "actions"
    max_attempts: int = 5
    integrate_method: str = "euler"
    speed_range: tuple[float, float] | None = (-10.0, 50.0)
    max_abs_curvature: float | None = 1.0
    chain: str = "independent"  # or "conversation": stages 2 and 3 continue one conversation
    answer_format: str = "text"  # or "structured": stage 3 constrained to the actions JSON schema
    inputs: str = "full"  # input ablation (lightemma.inputs): full, no-image, blank-image, no-history
    samples: int = 1  # K independent chains per frame (--samples K)

    def __post_init__(self) -> None:
        if type(self.samples) is not int or self.samples < 1:
            raise InputError(f"samples must be a whole number of at least 1, got {self.samples!r}")
        if self.reask not in REASK_MODES:
            raise InputError(f"reask must be one of {', '.join(REASK_MODES)}, got {self.reask!r}")
        if self.max_attempts < 1:
            raise InputError(f"max_attempts must be at least 1, got {self.max_attempts}")
        if self.integrate_method not in INTEGRATION_METHODS:
            raise InputError(
                f"integrate method must be one of {', '.join(INTEGRATION_METHODS)}, got {self.integrate_method!r}"
            )

        plausibility(self.speed_range, self.max_abs_curvature)  # ValueError for malformed limits
        if self.chain not in CHAINS:
            raise InputError(f"chain must be one of {', '.join(CHAINS)}, got {self.chain!r}")
        if self.answer_format not in ANSWER_FORMATS:
            raise InputError(f"answer format must be one of {', '.join(ANSWER_FORMATS)}, got {self.answer_format!r}")

        check_inputs(self.inputs)

    @property
    def parse_mode(self) -> str:
        """How stage-3 answers are parsed: ``json`` for structured answers, else ``lenient``."""
        return "json" if self.answer_format == "structured" else "lenient"

    def response_schema(self, stage: str) -> ResponseSchema | None:
        """The JSON schema ``stage``'s answer is constrained to (stage 3 of a structured run), else None."""
        if stage != "actions" or self.answer_format != "structured":
            return None

        return ACTIONS_SCHEMA

    def parse_record(self) -> dict[str, Any]:
        """How answers are parsed, as the run manifest records it (``params.parse``)."""
        return {"mode": self.parse_mode, **plausibility(self.speed_range, self.max_abs_curvature)}

    def to_dict(self) -> dict[str, Any]:
        out = {
            "temperature": self.params.temperature,
            "max_tokens": self.params.max_tokens,
            "reask": self.reask,
            "max_attempts": self.max_attempts,
            "integrate_method": self.integrate_method,
            "chain": self.chain,
            "answer_format": self.answer_format,
            "inputs": self.inputs,
            "parse": self.parse_record(),
        }
        if self.samples > 1:  # a one-chain run's params are as they always were
            out["samples"] = self.samples
        return out | describe_perturbation(self.inputs)  # a corruption's or history perturbation's definition


def _call_record(stage: str, result: ChatResult) -> CallRecord:
    """One call as stored in an attempt: text or error, usage, time, cost."""
    return call_record(
        stage=stage,
        text=result.text if result.ok else None,
        error=result.error,
        error_message=result.error_message,
        input_tokens=result.input_tokens,
        output_tokens=result.output_tokens,
        seconds=round(result.seconds, 4),
        cost_cents=result.cost_cents,
        cached=result.cached,
        retries=result.retries,
        finish_reason=result.finish_reason,
        reasoning_tokens=result.reasoning_tokens,
        cached_input_tokens=result.cached_input_tokens,
        cache_write_tokens=result.cache_write_tokens,
    )


def _sum(values: list[Any], *, unknown_is_none: bool) -> Any:
    """Sum of ``values``; None when any is None and ``unknown_is_none``, or when all are None."""
    known = [v for v in values if v is not None]
    if not known or (unknown_is_none and len(known) != len(values)):
        return None
    return sum(known)


def _totals(calls: list[CallRecord]) -> dict[str, Any]:
    return {
        "input_tokens": _sum([c["input_tokens"] for c in calls], unknown_is_none=True),
        "output_tokens": _sum([c["output_tokens"] for c in calls], unknown_is_none=True),
        "reasoning_tokens": _sum([c.get("reasoning_tokens") for c in calls], unknown_is_none=True),
        "cached_input_tokens": _sum([c.get("cached_input_tokens") for c in calls], unknown_is_none=True),
        "cache_write_tokens": _sum([c.get("cache_write_tokens") for c in calls], unknown_is_none=True),
        "seconds": round(sum(c["seconds"] or 0.0 for c in calls), 4),  # a chain's calls always have their time
        "cost_cents": _sum([c["cost_cents"] for c in calls], unknown_is_none=True),
    }


class _Attempt:
    """Collects the calls of one attempt."""

    def __init__(self, number: int) -> None:
        self.number = number
        self.calls: list[CallRecord] = []
        self.error: str | None = None
        self.truncated: str | None = None  # the stage whose text was cut off at the output-token limit

    def record(self, stage: str, result: ChatResult) -> str | None:
        """The call's text for the next step, or None when it failed or was cut off (never passed on)."""
        self.calls.append(_call_record(stage, result))
        if not result.ok:
            self.error = result.error or "Error"
            return None
        if is_truncated(result.finish_reason):
            self.truncated = stage
            return None
        return result.text

    def finish_truncated(self) -> AttemptRecord:
        """This attempt, ended by a text cut off at the output-token limit: ``failed``, ``failure: "truncated"``."""
        if self.truncated == "actions":
            return self.finish(self.calls[-1]["text"], "failed", "truncated", "truncated")
        return self.finish(
            None,
            "failed",
            f"truncated: the {self.truncated} text hit the output-token limit and was not passed on",
            "truncated",
        )

    def finish(self, answer: str | None, status: str, reason: str, failure: str) -> AttemptRecord:
        return attempt_record(
            attempt=self.number,
            calls=self.calls,
            answer=answer,
            status=status,
            reason=reason,
            failure=failure,
            error=self.error,
            **_totals(self.calls),
        )


def _parse(answer: str, policy: ChainPolicy, history: Any = None) -> tuple[str, str, str, np.ndarray]:
    """Parse of one answer (lenient; json for structured answers): (status, reason, failure kind, actions (6, 2)).

    ``history`` is the frame's (6, 2) history the prompt printed: a list in the answer equal to it is a
    quotation beside another list where the text calls it the past (see :func:`lightemma.parse_actions`).
    """
    parsed = parse_actions(
        [answer],
        n=6,
        mode=policy.parse_mode,
        speed_range=policy.speed_range,
        max_abs_curvature=policy.max_abs_curvature,
        history=history_rows([history]),
    )
    return (
        str(parsed.status[0]),
        str(parsed.reason[0]),
        str(parsed.failure[0]),
        np.asarray(parsed.actions[0], dtype=np.float64),
    )


def _as_list(value: Any) -> Any:
    return None if value is None else np.asarray(value, dtype=np.float64).tolist()


async def run_frame(
    frame: Any, backend: Backend, prompts: PromptSet, policy: ChainPolicy, earlier: Mapping[str, Any] | None = None
) -> dict[str, Any]:
    """Run the chain on one frame and return its run record (docs/definitions.md#run-records).

    ``frame`` needs ``frame_id``, ``scene_name``, ``sample_token``,
    ``image_path``, ``history_actions`` (6, 2) and ``gt_positions`` (6, 2).
    ``earlier`` is the frame's failed record from an earlier session (``--retry-failed``, or a
    frame that failed with the error that stopped the run): its attempts come first in the new
    record, numbered on, so FE still counts the first answer ever received and the frame's time,
    tokens and cost include what the earlier attempts spent; up to ``max_attempts`` new attempts
    are made.
    Raises only what the backend raises: :class:`~lightemma.errors.RunFatalError` when the run
    cannot succeed (a rejected API key, the same failure on frame after frame).

    With ``policy.samples`` K > 1 the frame runs K independent chains (see the module docstring); ``earlier``'s
    ``samples`` give each sample its own earlier attempts.
    """
    if policy.samples == 1:
        return await _run_chain(frame, backend, prompts, policy, earlier)
    start = time.perf_counter()
    k = policy.samples
    before: list[Mapping[str, Any] | None] = [earlier] + [None] * (k - 1)
    for entry in (earlier or {}).get("samples") or ():
        index = entry.get("sample") if isinstance(entry, Mapping) else None
        if type(index) is int and 0 < index < k:
            before[index] = entry
    first: list[ChatResult] | None = None
    if not any((b or {}).get("attempts") for b in before):  # a fresh frame: stage 1 of every sample in one go
        request = _request(
            frame, policy, "scene", prompts.render("scene"), (), 1, request_image(frame, policy.inputs), 0
        )
        first = await backend.generate_samples(request, k)
    tasks = [
        asyncio.ensure_future(
            _run_chain(
                frame, backend, prompts, policy, before[s], sample=s, first=first[s] if first is not None else None
            )
        )
        for s in range(k)
    ]
    try:
        records = await asyncio.gather(*tasks)
    except BaseException:  # a run-fatal error (or a stop) in one sample: the frame's other chains end with it
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        raise
    return _merge_samples(list(records), time.perf_counter() - start)


#: the fields of a sample's own entry in a frame record's ``samples`` list (docs/run.md#k-samples)
SAMPLE_FIELDS = (
    "status",
    "failure",
    "first_status",
    "n_attempts",
    "attempts",
    "actions",
    "trajectory",
    "scene_text",
    "intent_text",
    "answer",
    "error",
    "seconds",
    "call_seconds",
    "input_tokens",
    "output_tokens",
    "reasoning_tokens",
    "cached_input_tokens",
    "cache_write_tokens",
    "cost_cents",
    "cached",
    "cached_calls",
    "retries",
)
_SUMMED = (
    "input_tokens",
    "output_tokens",
    "reasoning_tokens",
    "cached_input_tokens",
    "cache_write_tokens",
    "cost_cents",
)


def _merge_samples(records: list[dict[str, Any]], seconds: float) -> dict[str, Any]:
    """The frame record of K samples' records: sample 0's fields where a one-chain record has them, the others
    (their :data:`SAMPLE_FIELDS`) in ``samples``; tokens, cost, call time, cache and retry counts summed over every
    sample (null when any sample's is); ``seconds`` the frame's wall time."""
    out = dict(records[0])
    out["samples"] = [{"sample": s, **{key: r[key] for key in SAMPLE_FIELDS}} for s, r in enumerate(records[1:], 1)]
    for key in _SUMMED:
        out[key] = _sum([r[key] for r in records], unknown_is_none=True)
    out["call_seconds"] = round(sum(r["call_seconds"] for r in records), 4)
    out["cached"] = any(r["cached"] for r in records)
    out["cached_calls"] = sum(r["cached_calls"] for r in records)
    out["retries"] = sum(r["retries"] for r in records)
    out["seconds"] = round(seconds, 4)
    return out


def _request(
    frame: Any,
    policy: ChainPolicy,
    stage: str,
    text: str,
    turns: tuple[tuple[str, str], ...],
    attempt: int,
    image: str | None,
    sample: int,
) -> ChatRequest:
    """The request of one stage of one sample's chain."""
    return ChatRequest(
        text=text,
        stage=stage,
        frame_id=frame.frame_id,
        image_path=image,
        params=policy.params,
        frame=frame,
        turns=turns,
        response_schema=policy.response_schema(stage),
        prefix_of_next=policy.chain == "conversation" and stage != "actions",
        attempt=attempt,
        inputs=policy.inputs,
        sample=sample,
        samples=policy.samples,
    )


async def _run_chain(
    frame: Any,
    backend: Backend,
    prompts: PromptSet,
    policy: ChainPolicy,
    earlier: Mapping[str, Any] | None = None,
    *,
    sample: int = 0,
    first: ChatResult | None = None,
) -> dict[str, Any]:
    """One chain of ``frame`` (sample ``sample``): its record as :func:`run_frame` describes it. ``first``: the
    answer to its first stage-1 request, already drawn."""
    start = time.perf_counter()
    shown = shown_history(frame, policy.inputs)  # the frame's history, or its perturbation (--inputs history-*)
    history = history_placeholders(shown)  # {history}, {speeds}, {curvatures}
    image = request_image(frame, policy.inputs)  # the frame's image, a blank or corrupted one, or none (--inputs)
    drawn = [first] if first is not None else []

    async def ask(stage: str, text: str, turns: tuple[tuple[str, str], ...] = ()) -> ChatResult:
        if stage == "scene" and drawn:
            return drawn.pop()
        request = _request(frame, policy, stage, text, turns, attempt.number, image, sample)
        return (await backend.generate([request]))[0]

    def turns(*texts: str) -> tuple[tuple[str, str], ...]:
        return _earlier_turns(policy, prompts, history, *texts)

    before = [
        cast(AttemptRecord, a)
        for a in (earlier or {}).get("attempts") or ()
        if isinstance(a, Mapping) and isinstance(a.get("calls"), list)
    ]
    attempts: list[AttemptRecord] = []
    scene: str | None = None
    intent: str | None = None
    actions = None
    answer: str | None = None
    for number in range(len(before) + 1, len(before) + policy.max_attempts + 1):
        attempt = _Attempt(number)
        if policy.reask == "chain":
            scene = intent = None
        if scene is None:
            scene = attempt.record("scene", await ask("scene", prompts.render("scene")))
        if scene is not None and intent is None:
            intent = attempt.record(
                "intent", await ask("intent", prompts.render("intent", scene=scene, **history), turns(scene))
            )
        answer = None
        if scene is not None and intent is not None:
            answer = attempt.record(
                "actions",
                await ask(
                    "actions", prompts.render("actions", scene=scene, intent=intent, **history), turns(scene, intent)
                ),
            )
        if answer is None:
            if attempt.truncated:
                attempts.append(attempt.finish_truncated())
                answer = attempts[-1]["answer"]
            elif attempt.error == "EmptyResponse" and attempt.calls[-1]["stage"] == "actions":
                # the provider answered stage 3 with no text: a received answer that is empty, not an API error
                attempts.append(attempt.finish(None, "failed", "empty answer (EmptyResponse)", "format"))
            else:
                attempts.append(attempt.finish(None, "failed", f"API error: {attempt.error}", "api_error"))
            continue
        status, reason, failure, parsed = _parse(answer, policy, shown)
        attempts.append(attempt.finish(answer, status, reason, failure))
        if status != "failed":
            actions = parsed
            break

    seconds = time.perf_counter() - start + _number((earlier or {}).get("seconds"))
    record = _frame_record(frame, [*before, *attempts], scene, intent, answer, actions, policy, seconds)
    return cast(dict[str, Any], record)  # the runner and the samples merge still take records as plain dicts


def _number(value: Any) -> float:
    """A recorded non-negative number, else 0 (an earlier record without the field)."""
    return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) and value >= 0 else 0.0


def _earlier_turns(
    policy: ChainPolicy, prompts: PromptSet, history: dict[str, str], *texts: str
) -> tuple[tuple[str, str], ...]:
    """The (prompt, answer) turns before a stage in the conversation chain: scene, then intent (none when independent)."""
    if policy.chain != "conversation":
        return ()
    prompts_sent = (prompts.render("scene"), prompts.render("intent", scene=texts[0], **history))
    return tuple(zip(prompts_sent, texts))


def _frame_record(
    frame: Any,
    attempts: list[AttemptRecord],
    scene: str | None,
    intent: str | None,
    answer: str | None,
    actions: np.ndarray | None,
    policy: ChainPolicy,
    seconds: float,
) -> FrameRecord:
    trajectory = None
    if actions is not None:
        trajectory = integrate(actions, dt=STEP_SECONDS, method=policy.integrate_method)
    calls = [c for a in attempts for c in a["calls"]]
    last = attempts[-1]
    totals = _totals(calls)
    return frame_record(
        frame_id=frame.frame_id,
        scene_name=frame.scene_name,
        sample_token=frame.sample_token,
        status=last["status"],
        failure=last["failure"],
        # FE counts the first stage-3 answer received: an API error or a text cut off before stage 3 gives none
        first_status=next((a["status"] for a in attempts if attempt_received(a)), None),
        n_attempts=len(attempts),
        attempts=attempts,
        actions=_as_list(actions),
        trajectory=_as_list(trajectory),
        gt_positions=_as_list(frame.gt_positions),
        history_actions=_as_list(frame.history_actions),
        scene_text=scene,
        intent_text=intent,
        answer=answer,
        error=last["error"] if last["status"] == "failed" else None,
        seconds=round(seconds, 4),
        call_seconds=totals["seconds"],
        input_tokens=totals["input_tokens"],
        output_tokens=totals["output_tokens"],
        reasoning_tokens=totals["reasoning_tokens"],
        cached_input_tokens=totals["cached_input_tokens"],
        cache_write_tokens=totals["cache_write_tokens"],
        cost_cents=totals["cost_cents"],
        cached=any(c["cached"] for c in calls),
        cached_calls=sum(1 for c in calls if c["cached"]),
        retries=sum(c["retries"] for c in calls),
    )
