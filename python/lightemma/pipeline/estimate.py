"""Know the bill first: the calls, tokens and cost a run will take, computed without calling anything.

``lightemma run … --estimate`` prints it and exits; every run of a paid model prints its one-line form
before it starts, and ``--max-cost CENTS`` stops a run before it spends more (:class:`Budget`).

The estimate counts the first attempt of every frame: three calls, each with what ``--inputs`` shows the
model (:mod:`lightemma.inputs`): the frame's image (``full``, ``no-history``), a blank one of its size
(``blank-image``: the same image tokens) or none (``no-image``).

* Image tokens: the model's published rule at each frame's image size, read from the image file's header
  (:func:`lightemma.models.tokens.image_rule`: per model, each with its source and the date it was read). A model with
  no published rule has unknown image tokens: its input tokens and cost are unknown (None), never a guess, and
  ``--max-cost`` admits its calls at :func:`frame_cost_upper_bound` instead.
* Text tokens: the prompts of the run's variant (``no-history``: the no-history templates) as rendered for
  the frame (its history), at one token per 4 UTF-8 bytes (OpenAI's
  rule of thumb, platform.openai.com/tokenizer) plus 4 tokens of role markers per message; stages 2 and 3
  also carry the earlier stages' answers, taken as 45 % (scene) and 35 % (intent) of the frame's output.
* Output tokens: the registry's typical figure per frame (:func:`lightemma.models.tokens.typical_output_tokens`,
  the paper's Table I for its models), at most three times ``--max-tokens``.
* Cost: at the list price (:func:`lightemma.models.prices.price`) and the batch price
  (:func:`lightemma.models.prices.batch_price`); prompt-cache discounts are left out, so the figure errs high.

Re-asks (format errors, API errors) add calls the estimate does not foresee. A run with no provider bill
(a baseline, a local ``hf`` / ``vllm`` backend) has no estimate: :func:`no_bill` is its one line.

:func:`frame_cost_upper_bound` is the most one frame's chain (three calls, first attempts) can cost whatever its
images and answers: every call at the model's whole context window of input and ``--max-tokens`` plus the
reasoning budget of output (:class:`CostBound` says why each is a bound).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any

from lightemma.frames import history_placeholders
from lightemma.inputs import check_inputs
from lightemma.models.catalog import ModelInfo
from lightemma.models.prices import Price, _litellm_entry, reasoning_budget, run_price
from lightemma.models.tokens import IMAGE_TOKEN_RULES, image_rule, typical_output_tokens

SCENE_SHARE, INTENT_SHARE = 0.45, 0.35  # of a frame's output: the scene and intent answers, pasted into later prompts
MESSAGE_TOKENS = 4


def text_tokens(text: str) -> int:
    """Tokens of ``text`` at one per 4 UTF-8 bytes (rounded up)."""
    return math.ceil(len(text.encode("utf-8")) / 4)


def _image_size(path: str | None) -> tuple[int, int] | None:
    if not path:
        return None
    from PIL import Image

    try:
        with Image.open(path) as img:  # the header only
            return img.size
    except OSError:
        return None


@dataclass(frozen=True)
class CostBound:
    """The most one call of a run can cost, and why (:func:`frame_cost_upper_bound`).

    ``input_tokens``: the model's context window (litellm's ``max_input_tokens``: a provider refuses a longer request,
    so no call is billed more input); ``output_tokens``: ``--max-tokens`` plus the reasoning budget (the output limit
    each call is sent with). Input tokens are priced at the dearest input price the run may bill them at (a cache write
    included). ``cents_per_call`` is None where the price or the context window is unknown (``source`` says which).
    """

    cents_per_call: float | None
    input_tokens: int | None
    output_tokens: int
    source: str
    unknown: str | None = None  # what makes it no bound: "price" or "context window" (None: a bound)

    @property
    def cents_per_frame(self) -> float | None:
        """The bound of one frame's chain: three calls (first attempts; a re-ask is a call of its own)."""
        return None if self.cents_per_call is None else Budget.CHAIN_CALLS * self.cents_per_call


def frame_cost_upper_bound(
    info: ModelInfo,
    *,
    max_tokens: int,
    batch: bool = False,
    given_price: Sequence[float] | None = None,
    served_from: str | None = None,
) -> CostBound:
    """The upper bound of what one call (and, ``.cents_per_frame``, one frame's chain) of ``info`` can cost, in US
    cents, at the price the run bills (:func:`lightemma.models.prices.run_price`: ``given_price`` is ``--price``; a model
    ``served_from`` another ``--api-base`` has no list price and no known context window).

    For ``--max-cost`` where an estimate is not a bound (image tokens with no published rule): input at the model's
    whole context window, output at ``max_tokens`` + :func:`lightemma.models.prices.reasoning_budget`. Where the price or the
    window is unknown, ``cents_per_call`` is None (no bound), with the reason in ``source``: never a guessed figure.
    """
    output = int(max_tokens) + reasoning_budget(info)
    p = run_price(info, batch=batch, given=given_price, served_from=served_from)
    if p["input_usd_per_mtok"] is None or p["output_usd_per_mtok"] is None:
        return CostBound(None, None, output, f"the price is unknown ({p['source']})", unknown="price")
    window = None if served_from is not None else _litellm_entry(info.model_id).get("max_input_tokens")
    if not isinstance(window, int) or isinstance(window, bool) or window < 1:
        where = f"a model served from {served_from}" if served_from is not None else "not in litellm's bundled list"
        return CostBound(None, None, output, f"its context window is unknown ({where})", unknown="context window")
    prices = (p["input_usd_per_mtok"], p.get("cache_write_usd_per_mtok"), p.get("cache_read_usd_per_mtok"))
    dearest = max(x for x in prices if x is not None)
    cents = (window * dearest + output * p["output_usd_per_mtok"]) / 1e6 * 100.0
    return CostBound(
        cents,
        window,
        output,
        f"{window:,} input tokens (the context window: litellm's "
        f"max_input_tokens) + {output:,} output tokens (--max-tokens + reasoning budget) per call at "
        f"{p['source']}",
    )


@dataclass(frozen=True)
class Estimate:
    """What a run is expected to take (first attempts only).

    ``image_tokens``, ``input_tokens`` and the costs are None where the model's image tokens are unknown (no
    published rule, ``inputs`` showing images); ``bound`` / ``batch_bound`` are then what ``--max-cost`` admits
    calls at.
    """

    model: str
    provider: str
    frames: int
    calls: int
    input_tokens: int | None
    image_tokens: int | None  # of input_tokens; None: no published rule for the model's images
    output_tokens: int
    image_sizes: dict[str, int]  # "W×H" -> frames
    missing_images: int  # frames whose image could not be read (counted without an image)
    cost_cents: float | None  # at the list price; None when unknown or not per token
    batch_cost_cents: float | None  # at the batch price
    price_source: str
    batch_price_source: str
    output_source: str
    image_rule: str
    inputs: str = "full"  # the input ablation estimated (lightemma.inputs)
    text_tokens: int = 0  # of input_tokens: the prompts and pasted answers
    image_rule_exact: bool = True  # False: the rule gives a documented maximum per image (counted at it)
    bound: CostBound | None = None  # per call at the list price, where image tokens are unknown (for --max-cost)
    batch_bound: CostBound | None = None  # the same at the batch price
    samples: int = 1  # K chains per frame (--samples): calls, tokens and costs count each frame K times

    def to_dict(self) -> dict[str, Any]:
        out = asdict(self)
        if self.samples == 1:  # a one-chain run's estimate as it always was recorded
            del out["samples"]
        return out

    @property
    def cents_per_call(self) -> float | None:
        return None if self.cost_cents is None or not self.calls else self.cost_cents / self.calls

    @property
    def batch_cents_per_call(self) -> float | None:
        return None if self.batch_cost_cents is None or not self.calls else self.batch_cost_cents / self.calls

    def admitted_cents_per_call(self, batch: bool = False) -> float | None:
        """What ``--max-cost`` admits each call at (US cents): the estimate per call (batch price with ``batch``) where
        the image tokens are known, else the call's upper bound (:func:`frame_cost_upper_bound`); None where neither is
        known (the price, or the context window of a model whose image tokens are unknown)."""
        if self.image_tokens is not None:
            return self.batch_cents_per_call if batch else self.cents_per_call
        bound = self.batch_bound if batch else self.bound
        return None if bound is None else bound.cents_per_call

    def line(self) -> str:
        """The one-line form printed before every paid run."""
        sizes = ", ".join(f"{size}" for size in self.image_sizes) or "no image"
        if self.inputs == "blank-image" and self.image_sizes:
            sizes += " blank"

        def money(cents: float | None) -> str:
            return "unknown" if cents is None else f"~${cents / 100:,.2f}"

        if self.image_tokens is None:  # no published rule: the image part is unknown, and so is the total
            inputs = (
                f"~{self.text_tokens:,} text input tokens + unknown image tokens (no published image rule for "
                f"{self.model}; {sizes})"
            )
        else:
            at_most = "at most " if not self.image_rule_exact else ""
            images = (
                "0 image: --inputs no-image"
                if self.inputs == "no-image"
                else f"{at_most}{self.image_tokens:,} image, {sizes}, {self.provider} rule"
            )
            inputs = f"~{self.input_tokens:,} input tokens ({images})"
        frames = f"{self.frames:,} frames × {self.samples} samples" if self.samples > 1 else f"{self.frames:,} frames"
        return (
            f"estimate: {frames}, {self.calls:,} calls, {inputs} + ~{self.output_tokens:,} output "
            f"tokens: {money(self.cost_cents)} normal, {money(self.batch_cost_cents)} with --batch"
        )

    def report(self) -> str:
        """The ``--estimate`` report: the line, then where each figure comes from."""
        lines = [
            self.line(),
            f"  image tokens: {'none (--inputs no-image sends no image)' if self.inputs == 'no-image' else self.image_rule}",
            "  text tokens: the rendered prompts at 4 UTF-8 bytes per token + 4 per message",
            f"  output tokens: {self.output_tokens // max(self.frames, 1):,} per frame ({self.output_source})",
            f"  list price: {self.price_source}",
            f"  batch price: {self.batch_price_source}",
            "  first attempts only; re-asks add calls; prompt-cache discounts are left out (the figure errs high)",
        ]
        if self.image_tokens is None:
            for label, b in (("", self.bound), (" with --batch", self.batch_bound)):
                if b is None:
                    continue
                lines.append(
                    f"  --max-cost{label}: no bound known ({b.source}); refused"
                    if b.cents_per_call is None
                    else f"  --max-cost{label}: each call admitted at its upper bound, "
                    f"{b.cents_per_call:.3f} ¢: {b.source}"
                )
        return "\n".join(lines)


def no_bill(model: str, kind: str, frames: int) -> str:
    """The one line ``--estimate`` prints for a run with no provider bill: a baseline or a local backend (``kind``)."""
    where = (
        "here as a baseline, from the frame's numbers (no model)"
        if kind == "baseline"
        else f"on this machine through the {kind} backend (local compute)"
    )
    return f"estimate: {frames:,} frames, 0 calls to a provider, no cost: {model} runs {where}; there is no bill to estimate"


def estimate(
    frames: Sequence[Any],
    info: ModelInfo,
    provider: str | None,
    prompts: Any,
    *,
    max_tokens: int,
    chain: str = "independent",
    inputs: str = "full",
    given_price: Sequence[float] | None = None,
    served_from: str | None = None,
    samples: int = 1,
) -> Estimate:
    """The :class:`Estimate` of running ``info`` over ``frames`` with ``prompts`` (a PromptSet selected for the run's
    variant, ``inputs`` included); ``inputs`` ``no-image`` counts no image token. Priced as the run bills its calls
    (:func:`lightemma.models.prices.run_price`): at ``given_price`` (``--price``) when given, unknown when the model is
    served from another ``--api-base`` (``served_from``, as shown), else at the list and batch prices. ``samples``
    (K chains per frame, ``--samples``) counts every call, token and cent K times (one request with ``n`` sends
    stage 1's input once: the figure errs high)."""
    check_inputs(inputs)
    rule_provider = provider if provider in ("anthropic", "gemini", "vertex_ai") else "openai"
    rule = image_rule(info)
    shows_images = inputs != "no-image"
    typical, output_source = typical_output_tokens(info)
    out_per_frame = min(typical, 3 * max_tokens)
    scene_out, intent_out = (
        "x" * (4 * round(out_per_frame * SCENE_SHARE)),
        "x" * (4 * round(out_per_frame * INTENT_SHARE)),
    )
    sizes: dict[str, int] = {}
    cache: dict[str, tuple[int, int] | None] = {}
    image_total = text_total = missing = 0
    for frame in frames:
        path = str(getattr(frame, "image_path", "") or "")
        if path not in cache and inputs != "no-image":
            cache[path] = _image_size(path)
        size = cache.get(path)
        if inputs == "no-image":  # no image in any stage
            pass
        elif size is None:
            missing += 1
        else:  # the frame's image, or a blank one of its size (the same tokens)
            sizes[f"{size[0]}×{size[1]}"] = sizes.get(f"{size[0]}×{size[1]}", 0) + 1
            if rule is not None:
                image_total += 3 * rule.tokens(size[0], size[1])
        history = history_placeholders(frame.history_actions)
        texts = [
            prompts.render("scene"),
            prompts.render("intent", scene=scene_out, **history),
            prompts.render("actions", scene=scene_out, intent=intent_out, **history),
        ]
        messages = (1, 3, 5) if chain == "conversation" else (1, 1, 1)
        if chain == "conversation":  # the earlier prompts and answers are resent as turns
            texts[1] += texts[0] + scene_out
            texts[2] += texts[1] + intent_out
        text_total += sum(text_tokens(t) + MESSAGE_TOKENS * m for t, m in zip(texts, messages))
    n = len(frames)
    output = out_per_frame * n * samples
    image_total, text_total = image_total * samples, text_total * samples
    unknown_images = shows_images and rule is None
    images: int | None = None if unknown_images else image_total
    total_in = None if images is None else images + text_total
    list_price = run_price(info, given=given_price, served_from=served_from)
    batch = run_price(info, batch=True, given=given_price, served_from=served_from)

    def cost(p: Price) -> float | None:
        if total_in is None or p["input_usd_per_mtok"] is None or p["output_usd_per_mtok"] is None:
            return None
        return (total_in * p["input_usd_per_mtok"] + output * p["output_usd_per_mtok"]) / 1e6 * 100.0

    if rule is not None:
        rule_text = rule.describe()
    else:
        family = IMAGE_TOKEN_RULES[rule_provider if rule_provider != "vertex_ai" else "gemini"]
        rule_text = (
            f"unknown: no published image rule for {info.model_id} (lightemma.models.tokens.IMAGE_RULES says which "
            f"rules are and why others are left out; the provider's rules: {family})"
        )
    bounds = {}
    if unknown_images:
        bounds = {
            key: frame_cost_upper_bound(
                info, max_tokens=max_tokens, batch=is_batch, given_price=given_price, served_from=served_from
            )
            for key, is_batch in (("bound", False), ("batch_bound", True))
        }
    # the label names the rule counted (the model's own), not the route: Claude behind --api-base is 'anthropic rule'
    label = rule.provider if rule is not None else rule_provider
    return Estimate(
        model=info.key,
        provider=label,
        frames=n,
        calls=3 * n * samples,
        samples=samples,
        input_tokens=total_in,
        image_tokens=images,
        output_tokens=output,
        image_sizes=sizes,
        missing_images=missing,
        cost_cents=cost(list_price),
        batch_cost_cents=cost(batch),
        price_source=list_price["source"],
        batch_price_source=batch["source"],
        output_source=output_source,
        image_rule=rule_text,
        inputs=inputs,
        text_tokens=text_total,
        image_rule_exact=rule is None or rule.exact,
        **bounds,
    )


class Budget:
    """``--max-cost``: a frame starts only while what was spent, what the frames in flight are expected to spend
    and its own whole chain's expected cost (three calls) stay within ``limit_cents``; a call beyond the chain
    it reserved (a re-ask) needs room of its own. ``spent_cents`` starts at what the run's records already cost.
    """

    CHAIN_CALLS = 3

    def __init__(
        self, limit_cents: float, per_call_cents: float, spent_cents: float = 0.0, chain_calls: int = CHAIN_CALLS
    ) -> None:
        self.chain_calls = int(chain_calls)  # the calls a frame's first call reserves: 3 × K with --samples K
        self.limit_cents = float(limit_cents)
        self.per_call_cents = float(per_call_cents)
        self.spent_cents = float(spent_cents)
        self.reserved_cents = 0.0
        self._held: dict[str, int] = {}  # frame id -> calls of its chain reserved and not yet made

    def _room(self, calls: int) -> bool:
        return self.spent_cents + self.reserved_cents + self.per_call_cents * calls <= self.limit_cents

    def reserve(self, frame_id: str, first_call: bool) -> float | None:
        """Reserve one call of ``frame_id`` (its first call reserves the whole chain); the cents now held for
        this call, or None (nothing reserved) when it does not fit."""
        held = self._held.get(frame_id, 0)
        if held > 0:
            self._held[frame_id] = held - 1
            return self.per_call_cents
        calls = self.chain_calls if first_call and frame_id not in self._held else 1
        if not self._room(calls):
            return None
        self.reserved_cents += self.per_call_cents * calls
        self._held[frame_id] = calls - 1
        return self.per_call_cents

    def settle(self, reserved: float, spent: float) -> None:
        """A call ended: its reservation is released, what it cost is spent."""
        self.reserved_cents -= reserved
        self.spent_cents += spent

    def release(self, frame_id: str) -> None:
        """A frame ended: the calls of its chain it did not make are released."""
        self.reserved_cents -= self.per_call_cents * self._held.pop(frame_id, 0)

    def message(self) -> str:
        return (
            f"--max-cost {self.limit_cents:g}: {self.spent_cents:.2f} ¢ spent and {max(self.reserved_cents, 0.0):.2f} ¢ in flight; "
            f"the next frame (about {self.chain_calls * self.per_call_cents:.3f} ¢) would pass the limit"
        )
