"""Know the bill first: the calls, tokens and cost a run will take, computed without calling anything.

``lightemma run … --estimate`` prints it and exits; every run of a paid model prints its one-line form
before it starts, and ``--max-cost CENTS`` stops a run before it spends more (:class:`Budget`).

The estimate counts the first attempt of every frame: three calls, each with what ``--inputs`` shows the
model (:mod:`lightemma.inputs`): the frame's image (``full``, ``no-history``), a blank one of its size
(``blank-image``: the same image tokens) or none (``no-image``).

* Image tokens: the provider's published rule at each frame's image size, read from the image file's
  header (:func:`lightemma.registry.image_tokens`; sources in :data:`lightemma.registry.IMAGE_TOKEN_RULES`).
* Text tokens: the prompts of the run's variant (``no-history``: the no-history templates) as rendered for
  the frame (its history), at one token per 4 UTF-8 bytes (OpenAI's
  rule of thumb, platform.openai.com/tokenizer) plus 4 tokens of role markers per message; stages 2 and 3
  also carry the earlier stages' answers, taken as 45 % (scene) and 35 % (intent) of the frame's output.
* Output tokens: the registry's typical figure per frame (:func:`lightemma.registry.typical_output_tokens`,
  the paper's Table I for its models), at most three times ``--max-tokens``.
* Cost: at the list price (:func:`lightemma.registry.price`) and the batch price
  (:func:`lightemma.registry.batch_price`); prompt-cache discounts are left out, so the figure errs high.

Re-asks (format errors, API errors) add calls the estimate does not foresee. A run with no provider bill
(a baseline, a local ``hf`` / ``vllm`` backend) has no estimate: :func:`no_bill` is its one line.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any

from lightemma.registry import ModelInfo, image_tokens, run_price, typical_output_tokens

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
class Estimate:
    """What a run is expected to take (first attempts only)."""

    model: str
    provider: str
    frames: int
    calls: int
    input_tokens: int
    image_tokens: int  # of input_tokens
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

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @property
    def cents_per_call(self) -> float | None:
        return None if self.cost_cents is None or not self.calls else self.cost_cents / self.calls

    @property
    def batch_cents_per_call(self) -> float | None:
        return None if self.batch_cost_cents is None or not self.calls else self.batch_cost_cents / self.calls

    def line(self) -> str:
        """The one-line form printed before every paid run."""
        sizes = ", ".join(f"{size}" for size in self.image_sizes) or "no image"
        if self.inputs == "blank-image" and self.image_sizes:
            sizes += " blank"
        images = ("0 image: --inputs no-image" if self.inputs == "no-image"
                  else f"{self.image_tokens:,} image, {sizes}, {self.provider} rule")

        def money(cents: float | None) -> str:
            return "unknown" if cents is None else f"~${cents / 100:,.2f}"

        return (f"estimate: {self.frames:,} frames, {self.calls:,} calls, ~{self.input_tokens:,} input tokens "
                f"({images}) + ~{self.output_tokens:,} output tokens: "
                f"{money(self.cost_cents)} normal, {money(self.batch_cost_cents)} with --batch")

    def report(self) -> str:
        """The ``--estimate`` report: the line, then where each figure comes from."""
        return "\n".join([
            self.line(),
            f"  image tokens: {'none (--inputs no-image sends no image)' if self.inputs == 'no-image' else self.image_rule}",
            "  text tokens: the rendered prompts at 4 UTF-8 bytes per token + 4 per message",
            f"  output tokens: {self.output_tokens // max(self.frames, 1):,} per frame ({self.output_source})",
            f"  list price: {self.price_source}",
            f"  batch price: {self.batch_price_source}",
            "  first attempts only; re-asks add calls; prompt-cache discounts are left out (the figure errs high)",
        ])


def no_bill(model: str, kind: str, frames: int) -> str:
    """The one line ``--estimate`` prints for a run with no provider bill: a baseline or a local backend (``kind``)."""
    where = "here as a baseline, from the frame's numbers (no model)" if kind == "baseline" else \
        f"on this machine through the {kind} backend (local compute)"
    return f"estimate: {frames:,} frames, 0 calls to a provider, no cost: {model} runs {where}; there is no bill to estimate"


def estimate(frames: Sequence[Any], info: ModelInfo, provider: str | None, prompts: Any, *, max_tokens: int,
             chain: str = "independent", inputs: str = "full", given_price: Sequence[float] | None = None,
             served_from: str | None = None) -> Estimate:
    """The :class:`Estimate` of running ``info`` over ``frames`` with ``prompts`` (a PromptSet selected for the run's
    variant, ``inputs`` included); ``inputs`` ``no-image`` counts no image token. Priced as the run bills its calls
    (:func:`lightemma.registry.run_price`): at ``given_price`` (``--price``) when given, unknown when the model is
    served from another ``--api-base`` (``served_from``, as shown), else at the list and batch prices."""
    from lightemma.frames import history_placeholders
    from lightemma.inputs import check_inputs
    from lightemma.registry import IMAGE_TOKEN_RULES

    check_inputs(inputs)
    rule_provider = provider if provider in ("anthropic", "gemini", "vertex_ai") else "openai"
    typical, output_source = typical_output_tokens(info)
    out_per_frame = min(typical, 3 * max_tokens)
    scene_out, intent_out = "x" * (4 * round(out_per_frame * SCENE_SHARE)), "x" * (4 * round(out_per_frame * INTENT_SHARE))
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
            image_total += 3 * image_tokens(size[0], size[1], rule_provider)
        history = history_placeholders(frame.history_actions)
        texts = [prompts.render("scene"), prompts.render("intent", scene=scene_out, **history),
                 prompts.render("actions", scene=scene_out, intent=intent_out, **history)]
        messages = (1, 3, 5) if chain == "conversation" else (1, 1, 1)
        if chain == "conversation":  # the earlier prompts and answers are resent as turns
            texts[1] += texts[0] + scene_out
            texts[2] += texts[1] + intent_out
        text_total += sum(text_tokens(t) + MESSAGE_TOKENS * m for t, m in zip(texts, messages))
    n = len(frames)
    output = out_per_frame * n
    total_in = image_total + text_total
    list_price = run_price(info, given=given_price, served_from=served_from)
    batch = run_price(info, batch=True, given=given_price, served_from=served_from)

    def cost(p: dict[str, Any]) -> float | None:
        if p["input_usd_per_mtok"] is None or p["output_usd_per_mtok"] is None:
            return None
        return (total_in * p["input_usd_per_mtok"] + output * p["output_usd_per_mtok"]) / 1e6 * 100.0

    return Estimate(model=info.key, provider=rule_provider, frames=n, calls=3 * n, input_tokens=total_in,
                    image_tokens=image_total, output_tokens=output, image_sizes=sizes, missing_images=missing,
                    cost_cents=cost(list_price), batch_cost_cents=cost(batch), price_source=list_price["source"],
                    batch_price_source=batch["source"], output_source=output_source,
                    image_rule=IMAGE_TOKEN_RULES[rule_provider if rule_provider != "vertex_ai" else "gemini"], inputs=inputs)


class Budget:
    """``--max-cost``: a frame starts only while what was spent, what the frames in flight are expected to spend
    and its own whole chain's expected cost (three calls) stay within ``limit_cents``; a call beyond the chain
    it reserved (a re-ask) needs room of its own. ``spent_cents`` starts at what the run's records already cost.
    """

    CHAIN_CALLS = 3

    def __init__(self, limit_cents: float, per_call_cents: float, spent_cents: float = 0.0) -> None:
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
        calls = self.CHAIN_CALLS if first_call and frame_id not in self._held else 1
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
        return (f"--max-cost {self.limit_cents:g}: {self.spent_cents:.2f} ¢ spent and {max(self.reserved_cents, 0.0):.2f} ¢ in flight; "
                f"the next frame (about {self.CHAIN_CALLS * self.per_call_cents:.3f} ¢) would pass the limit")
