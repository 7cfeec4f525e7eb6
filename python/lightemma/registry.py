"""The model registry: the paper's 15 models, the baselines, and any other model string.

Each paper model carries its display name exactly as in the paper's tables,
its family, its generation order within the family (1 = oldest), how it is
reached (``api`` through litellm, or a local ``hf`` checkpoint also servable by
``vllm``), the H100 GPUs the paper used, and its price.

API ids were checked against litellm's bundled price list
(``litellm.model_cost``, litellm 1.106.2). Where that list lacks a paper model
the entry carries the provider's list price itself, with where and when it was
read (``price_source``, ``price_read``); litellm's price wins whenever it has one.

Reasoning models (GPT-5.x, Gemini 2.5 and later) spend output tokens on hidden
reasoning before the answer, and providers count those against the output limit:
with the paper's 512 tokens per stage they can spend everything on reasoning and
return no answer. Their entries carry ``reasoning_budget``, output tokens sent on top
of ``--max-tokens`` so that the answer keeps its own room (the reasoning effort stays
the provider's default, as the paper ran them). Claude models reason only with
extended thinking, which lightemma does not request. A model outside the registry
that litellm's list marks as reasoning gets :data:`DEFAULT_REASONING_BUDGET`.

Batch prices (``lightemma run --batch``, :func:`batch_price`) come from litellm's bundled
``*_cost_per_token_batches`` where it has them, else from the registry's own entries (with their
source), else the list price at the providers' 50 % batch discount. :func:`image_rule` gives each model's
published image-token rule (:data:`IMAGE_RULES`, each with its source and the date it was read; None where no rule
is published), which ``--estimate`` and ``--max-cost`` use.

Anything not in the registry is taken as a litellm model string
(``anthropic/…``, ``gemini/…``, ``openai/NAME`` with ``--api-base``, …).
``lightemma models`` prints the registry.
"""

from __future__ import annotations

import functools
import importlib.util
import json
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from lightemma.errors import UserError

ANTHROPIC_PRICES = "docs.anthropic.com/en/docs/about-claude/pricing (stored copy)"
GOOGLE_PRICES = "ai.google.dev/gemini-api/docs/pricing (as quoted by morphllm.com/gemini-api-pricing, stored copy)"
PRICE_READ = "2026-11-22"
# Batch prices: 50 % of the interactive price for input and output tokens at all three providers.
OPENAI_BATCH_PRICES = "platform.openai.com/docs/guides/batch (50 % of the synchronous price; per model in litellm's list)"
ANTHROPIC_BATCH_PRICES = "docs.anthropic.com/en/docs/build-with-claude/batch-processing#pricing (50 % of standard prices)"
GOOGLE_BATCH_PRICES = "ai.google.dev/gemini-api/docs/batch-mode (50 % of the interactive price)"
BATCH_DISCOUNT = 0.5
#: output tokens added to --max-tokens for a reasoning model's hidden reasoning
DEFAULT_REASONING_BUDGET = 8192


@dataclass(frozen=True)
class ModelInfo:
    """One model: how to name it, reach it, and price it."""

    key: str  # registry key, e.g. "gpt-4o"
    display_name: str  # as in the paper's tables, e.g. "GPT-4o"
    family: str  # GPT, Claude, Gemini, Qwen, LLaMA, baseline, or "other"
    generation: int  # order within the family, 1 = oldest (0 = not a paper model)
    model_id: str  # litellm model string (api) or Hugging Face checkpoint (hf / vllm)
    backend: str  # "api" | "hf" | "vllm" | "baseline"
    gpus: int = 0  # H100 GPUs the paper used (local models)
    # Price in USD per million tokens when litellm's bundled list lacks the model.
    input_usd_per_mtok: float | None = None
    output_usd_per_mtok: float | None = None
    price_source: str | None = None
    price_read: str | None = None
    # Prompt-cache prices (USD per million tokens, same source) when litellm's list lacks the model:
    # tokens read from the provider's prompt cache, and tokens written to it (Anthropic bills writes above input).
    cache_read_usd_per_mtok: float | None = None
    cache_write_usd_per_mtok: float | None = None
    # Batch-API prices (USD per million tokens) when litellm's list lacks them, with their source.
    batch_input_usd_per_mtok: float | None = None
    batch_output_usd_per_mtok: float | None = None
    batch_price_source: str | None = None
    # Some providers reject temperature 0 (gpt-5 family: only the default, 1, while
    # reasoning); False means "send no temperature, the provider default applies".
    supports_temperature: bool = True
    in_paper: bool = True
    # Hidden reasoning before the answer (counted as output tokens by the provider), and the
    # output tokens sent on top of --max-tokens for it; 0 for models that answer directly.
    reasoning: bool = False
    reasoning_budget: int = 0

    def to_dict(self) -> dict[str, Any]:
        """JSON-able form, recorded in run manifests."""
        return asdict(self)

    @property
    def needs_api_key(self) -> bool:
        return self.backend == "api"


def _api(key: str, display: str, family: str, gen: int, model_id: str, **kw: Any) -> ModelInfo:
    return ModelInfo(key=key, display_name=display, family=family, generation=gen, model_id=model_id, backend="api", **kw)


def _local(key: str, display: str, family: str, gen: int, checkpoint: str, gpus: int) -> ModelInfo:
    return ModelInfo(key=key, display_name=display, family=family, generation=gen, model_id=checkpoint, backend="hf", gpus=gpus)


_REASONS = dict(reasoning=True, reasoning_budget=DEFAULT_REASONING_BUDGET)
# Sonnet 3.7 and 4: $3 input, $15 output, cache hits $0.30, 5-minute cache writes $3.75 per million tokens
_ANTHROPIC_SONNET = dict(input_usd_per_mtok=3.0, output_usd_per_mtok=15.0, cache_read_usd_per_mtok=0.30,
                         cache_write_usd_per_mtok=3.75, price_source=ANTHROPIC_PRICES, price_read=PRICE_READ,
                         batch_input_usd_per_mtok=1.5, batch_output_usd_per_mtok=7.5, batch_price_source=ANTHROPIC_BATCH_PRICES)

PAPER_MODELS: tuple[ModelInfo, ...] = (
    _api("gpt-4o", "GPT-4o", "GPT", 1, "gpt-4o"),
    _api("gpt-5.0", "GPT-5.0", "GPT", 2, "gpt-5", supports_temperature=False, **_REASONS),
    _api("gpt-5.2", "GPT-5.2", "GPT", 3, "gpt-5.2", supports_temperature=False, **_REASONS),
    _api("claude-3.7-sonnet", "Claude-3.7-Sonnet", "Claude", 1, "anthropic/claude-3-7-sonnet-20250219", **_ANTHROPIC_SONNET),
    _api("claude-4.0-sonnet", "Claude-4.0-Sonnet", "Claude", 2, "anthropic/claude-sonnet-4-20250514", **_ANTHROPIC_SONNET),
    _api("claude-4.6-sonnet", "Claude-4.6-Sonnet", "Claude", 3, "anthropic/claude-sonnet-4-6"),
    _api("gemini-2.0-flash", "Gemini-2.0-Flash", "Gemini", 1, "gemini/gemini-2.0-flash",
         input_usd_per_mtok=0.10, output_usd_per_mtok=0.40, price_source=GOOGLE_PRICES, price_read=PRICE_READ,
         batch_input_usd_per_mtok=0.05, batch_output_usd_per_mtok=0.20, batch_price_source=GOOGLE_BATCH_PRICES),
    _api("gemini-2.5-flash", "Gemini-2.5-Flash", "Gemini", 2, "gemini/gemini-2.5-flash", **_REASONS),
    _api("gemini-3.0-flash", "Gemini-3.0-Flash", "Gemini", 3, "gemini/gemini-3-flash-preview", **_REASONS),
    _local("qwen-2.0-vl-7b", "Qwen-2.0-VL-7B", "Qwen", 1, "Qwen/Qwen2-VL-7B-Instruct", 1),
    _local("qwen-2.5-vl-7b", "Qwen-2.5-VL-7B", "Qwen", 2, "Qwen/Qwen2.5-VL-7B-Instruct", 1),
    _local("qwen-3.0-vl-8b", "Qwen-3.0-VL-8B", "Qwen", 3, "Qwen/Qwen3-VL-8B-Instruct", 1),
    _local("llama-3.2-11b", "LLaMA-3.2-11B", "LLaMA", 1, "meta-llama/Llama-3.2-11B-Vision-Instruct", 1),
    _local("llama-3.2-90b", "LLaMA-3.2-90B", "LLaMA", 2, "meta-llama/Llama-3.2-90B-Vision-Instruct", 3),
    _local("llama-4.0-17b-scout", "LLaMA-4.0-17B-Scout", "LLaMA", 3, "meta-llama/Llama-4-Scout-17B-16E-Instruct", 3),
)

BASELINES: tuple[ModelInfo, ...] = tuple(
    ModelInfo(key=f"baseline:{kind}", display_name=f"Baseline ({label})", family="baseline", generation=0,
              model_id=f"baseline:{kind}", backend="baseline", in_paper=False)
    for kind, label in (("constant", "constant actions"), ("cv", "constant velocity"), ("oracle", "oracle actions"),
                        ("ego", "ego status"))
)

MODELS: tuple[ModelInfo, ...] = PAPER_MODELS + BASELINES


def _norm(name: str) -> str:
    return name.strip().lower()


_INDEX: dict[str, ModelInfo] = {}
for _m in MODELS:
    for _name in (_m.key, _m.display_name, _m.model_id):
        _INDEX.setdefault(_norm(_name), _m)


def lookup(name: str) -> ModelInfo | None:
    """The registry entry for a key, paper display name or provider id, or None."""
    return _INDEX.get(_norm(name))


def resolve(name: str) -> ModelInfo:
    """The registry entry for ``name``, or an ad-hoc entry for any other model string.

    ``baseline:KIND`` strings outside the registry are rejected with the known kinds.
    """
    if not name or not name.strip():
        raise UserError("--model is empty; give a registry name (see `lightemma models`) or a litellm model string")
    found = lookup(name)
    if found is not None:
        return found
    if _norm(name).startswith("baseline:"):
        kinds = ", ".join(m.key for m in BASELINES)
        raise UserError(f"unknown baseline {name!r}; known: {kinds}")
    return ModelInfo(key=name, display_name=name, family="other", generation=0, model_id=name, backend="api", in_paper=False)


# Model names the LightEMMA reference scripts use for their result folders
# (``<results>/<name>/output/*.json``, also ``metadata.model``) -> registry key.
# The older script versions used short names (``claude-3.7``, ``gemini-2.0``,
# ``qwen2.5-7b``); ``gemini-2.5`` meant Gemini 2.5 *Pro* there, which is not a
# paper row, so it is left unmapped. Names not listed stay as they are.
REFERENCE_NAMES: dict[str, str] = {
    "gpt-4o": "gpt-4o",
    "gpt-5": "gpt-5.0",
    "gpt-5.0": "gpt-5.0",
    "gpt-5.2": "gpt-5.2",
    "claude-3.7": "claude-3.7-sonnet",
    "claude-3.7-sonnet": "claude-3.7-sonnet",
    "claude-4": "claude-4.0-sonnet",
    "claude-4.0": "claude-4.0-sonnet",
    "claude-4-sonnet": "claude-4.0-sonnet",
    "claude-4.0-sonnet": "claude-4.0-sonnet",
    "claude-sonnet-4": "claude-4.0-sonnet",
    "claude-4.6": "claude-4.6-sonnet",
    "claude-4.6-sonnet": "claude-4.6-sonnet",
    "claude-sonnet-4.6": "claude-4.6-sonnet",
    "gemini-2.0": "gemini-2.0-flash",
    "gemini-2.0-flash": "gemini-2.0-flash",
    "gemini-2.5-flash": "gemini-2.5-flash",
    "gemini-3-flash": "gemini-3.0-flash",
    "gemini-3.0-flash": "gemini-3.0-flash",
    "qwen-2-7b": "qwen-2.0-vl-7b",
    "qwen-2.0-7b": "qwen-2.0-vl-7b",
    "qwen2-7b": "qwen-2.0-vl-7b",
    "qwen2.0-7b": "qwen-2.0-vl-7b",
    "qwen-2.5-7b": "qwen-2.5-vl-7b",
    "qwen2.5-7b": "qwen-2.5-vl-7b",
    "qwen-3-8b": "qwen-3.0-vl-8b",
    "qwen-3.0-8b": "qwen-3.0-vl-8b",
    "qwen3-8b": "qwen-3.0-vl-8b",
    "qwen3.0-8b": "qwen-3.0-vl-8b",
    "llama-3.2-11b": "llama-3.2-11b",
    "llama-3.2-90b": "llama-3.2-90b",
    "llama-4-scout": "llama-4.0-17b-scout",
    "llama-4.0-scout": "llama-4.0-17b-scout",
    "llama-4-17b-scout": "llama-4.0-17b-scout",
    "llama-4.0-17b-scout": "llama-4.0-17b-scout",
}


def reference_model(name: str) -> ModelInfo | None:
    """The registry entry a reference-script model name maps to (:data:`REFERENCE_NAMES`), else None.

    Registry keys and display names are accepted too (``GPT-4o``, ``qwen-2.5-vl-7b``).
    """
    key = REFERENCE_NAMES.get(_norm(name))
    if key is not None:
        return _INDEX[key]
    found = lookup(name)
    return found if found is not None and found.in_paper else None


_PRICE_LIST = "model_prices_and_context_window_backup.json"  # the list litellm loads with LITELLM_LOCAL_MODEL_COST_MAP


@functools.lru_cache(maxsize=1)
def bundled_price_list() -> dict[str, Any]:
    """litellm's bundled price list (``litellm.model_cost`` as lightemma loads it), read without importing litellm.

    Importing litellm takes seconds; the list is one JSON file inside the
    package. Falls back to ``litellm.model_cost`` where the file is not found.
    """
    spec = importlib.util.find_spec("litellm")
    for folder in (spec.submodule_search_locations or []) if spec else []:
        path = Path(folder) / _PRICE_LIST
        if path.is_file():
            return json.loads(path.read_bytes())
    from lightemma._litellm import litellm

    return litellm.model_cost


def reasoning_budget(info: ModelInfo) -> int:
    """Output tokens to send on top of ``--max-tokens`` for ``info``'s hidden reasoning (0: none).

    The registry's own value for its models; for any other model string, :data:`DEFAULT_REASONING_BUDGET`
    when litellm's bundled list marks it as reasoning (Anthropic models excepted: they reason only
    with extended thinking, which lightemma does not request).
    """
    if info.reasoning or lookup(info.key) is not None:
        return info.reasoning_budget
    reasons = _litellm_entry(info.model_id).get("supports_reasoning") is True
    return DEFAULT_REASONING_BUDGET if reasons and not _norm(info.model_id).startswith("anthropic/") else 0


def _litellm_entry(model_id: str) -> dict[str, Any]:
    """litellm's bundled price-list entry for ``model_id`` (with or without its provider prefix), or {}."""
    prices = bundled_price_list()
    entry = prices.get(model_id) or prices.get(model_id.split("/", 1)[-1])
    return entry if isinstance(entry, dict) else {}


def _litellm_version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("litellm")
    except PackageNotFoundError:  # pragma: no cover - litellm is a dependency
        return "?"


def price(info: ModelInfo) -> dict[str, Any]:
    """The price lightemma uses for ``info``: USD per million input/output tokens and where it comes from.

    litellm's bundled price list wins when it has the model; else the registry's own provider price
    (with its source and the date it was read); else unknown (``None`` prices: costs are recorded as null).
    Local models and baselines cost nothing per token (``source`` says so).
    """
    none = {"cache_read_usd_per_mtok": None, "cache_write_usd_per_mtok": None}
    if info.backend in ("hf", "vllm", "baseline"):
        kind = "no model" if info.backend == "baseline" else "local model: GPUs, not tokens"
        return {"input_usd_per_mtok": None, "output_usd_per_mtok": None, **none, "source": kind}
    entry = _litellm_entry(info.model_id)
    if entry.get("input_cost_per_token") is not None and entry.get("output_cost_per_token") is not None:
        def per_mtok(key: str) -> float | None:
            return float(entry[key]) * 1e6 if entry.get(key) is not None else None

        return {"input_usd_per_mtok": per_mtok("input_cost_per_token"), "output_usd_per_mtok": per_mtok("output_cost_per_token"),
                "cache_read_usd_per_mtok": per_mtok("cache_read_input_token_cost"),
                "cache_write_usd_per_mtok": per_mtok("cache_creation_input_token_cost"),
                "source": f"litellm {_litellm_version()} bundled price list"}
    if info.input_usd_per_mtok is not None and info.output_usd_per_mtok is not None:
        return {"input_usd_per_mtok": info.input_usd_per_mtok, "output_usd_per_mtok": info.output_usd_per_mtok,
                "cache_read_usd_per_mtok": info.cache_read_usd_per_mtok, "cache_write_usd_per_mtok": info.cache_write_usd_per_mtok,
                "source": f"{info.price_source}, read {info.price_read}"}
    return {"input_usd_per_mtok": None, "output_usd_per_mtok": None, **none, "source": "unknown (costs recorded as null)"}


def run_price(info: ModelInfo, *, batch: bool = False, given: Sequence[float] | None = None,
              served_from: str | None = None) -> dict[str, Any]:
    """The price a run bills its calls at, shaped like :func:`price`: ``given`` (``--price``: USD per million input /
    output tokens, for every call of the run, batched or not; cached and cache-write input tokens at the input
    price), else unknown when the model is
    served from another ``--api-base`` (``served_from``: not the provider's list price), else :func:`batch_price`
    (``batch``) or :func:`price`. :class:`~lightemma.backends.api.APIBackend` and
    :class:`~lightemma.backends.batch.BatchBackend` price calls this way, and ``--estimate`` / ``--max-cost`` with them."""
    none = {"cache_read_usd_per_mtok": None, "cache_write_usd_per_mtok": None}
    if given is not None:  # every input token at the input price: cached and cache-write ones too
        return {"input_usd_per_mtok": float(given[0]), "output_usd_per_mtok": float(given[1]),
                "cache_read_usd_per_mtok": float(given[0]), "cache_write_usd_per_mtok": float(given[0]),
                "source": f"--price {float(given[0]):g} {float(given[1]):g} (USD per million input / output tokens)"}
    if served_from is not None:
        return {"input_usd_per_mtok": None, "output_usd_per_mtok": None, **none, "source": f"none: served from {served_from}"}
    return batch_price(info) if batch else price(info)


def price_per_token(info: ModelInfo) -> tuple[float, float] | None:
    """(input, output) USD per token: litellm's bundled price when it has one, else the registry's."""
    if info.backend != "api":
        return None
    found = price(info)
    if found["input_usd_per_mtok"] is None or found["output_usd_per_mtok"] is None:
        return None
    return found["input_usd_per_mtok"] / 1e6, found["output_usd_per_mtok"] / 1e6


def cache_price_per_token(info: ModelInfo) -> tuple[float | None, float | None]:
    """(cache read, cache write) USD per token from the same source as :func:`price_per_token`; None where unknown."""
    if info.backend != "api":
        return None, None
    found = price(info)
    read, write = found["cache_read_usd_per_mtok"], found["cache_write_usd_per_mtok"]
    return (None if read is None else read / 1e6), (None if write is None else write / 1e6)


def batch_price(info: ModelInfo) -> dict[str, Any]:
    """The batch-API price of ``info`` (``lightemma run --batch``), shaped like :func:`price`.

    litellm's bundled ``*_cost_per_token_batches`` when it has them; else the registry's own batch prices
    (with their source); else the interactive price at the providers' batch discount
    (:data:`BATCH_DISCOUNT`, 50 % at OpenAI, Anthropic and Google). Cache-read and cache-write prices are
    the interactive ones at the same discount (Anthropic: batch and cache discounts stack). Unknown
    prices stay None.
    """
    base = price(info)
    if info.backend != "api" or base["input_usd_per_mtok"] is None or base["output_usd_per_mtok"] is None:
        return {**base, "discount": None}
    entry = _litellm_entry(info.model_id)
    if entry.get("input_cost_per_token_batches") is not None and entry.get("output_cost_per_token_batches") is not None:
        pin, pout = float(entry["input_cost_per_token_batches"]) * 1e6, float(entry["output_cost_per_token_batches"]) * 1e6
        source = f"litellm {_litellm_version()} bundled price list (batches)"
    elif info.batch_input_usd_per_mtok is not None and info.batch_output_usd_per_mtok is not None:
        pin, pout = info.batch_input_usd_per_mtok, info.batch_output_usd_per_mtok
        source = f"{info.batch_price_source}, read {info.price_read or PRICE_READ}"
    else:
        pin, pout = base["input_usd_per_mtok"] * BATCH_DISCOUNT, base["output_usd_per_mtok"] * BATCH_DISCOUNT
        source = f"{base['source']} at the batch discount ({BATCH_DISCOUNT:.0%}: {_batch_source(info)})"
    discount = pin / base["input_usd_per_mtok"] if base["input_usd_per_mtok"] else BATCH_DISCOUNT

    def scaled(key: str) -> float | None:
        return None if base[key] is None else base[key] * discount

    return {"input_usd_per_mtok": pin, "output_usd_per_mtok": pout, "cache_read_usd_per_mtok": scaled("cache_read_usd_per_mtok"),
            "cache_write_usd_per_mtok": scaled("cache_write_usd_per_mtok"), "source": source, "discount": discount}


def _batch_source(info: ModelInfo) -> str:
    model = _norm(info.model_id)
    if model.startswith("anthropic/") or "claude" in model:
        return ANTHROPIC_BATCH_PRICES
    if model.startswith(("gemini/", "vertex_ai/")):
        return GOOGLE_BATCH_PRICES
    return OPENAI_BATCH_PRICES


# --- image tokens, for estimates ------------------------------------------------------------------------
# Each rule below carries where it is published and the date it was read. Where the provider's own page could not be
# read as stored text, the copy that quotes it is named as well. A model whose rule is not published, or whose
# published readings disagree, has none (:func:`image_rule` returns None): its estimate says "unknown" for images and
# ``--max-cost`` counts its calls at :func:`lightemma.pipeline.estimate.frame_cost_upper_bound`, never at a guess.
IMAGE_RULES_READ = "2026-12-03"
OPENAI_VISION_DOC = "platform.openai.com/docs/guides/images-vision#calculating-costs"
ANTHROPIC_VISION_DOC = "docs.anthropic.com/en/docs/build-with-claude/vision#calculate-image-costs"
GEMINI_TOKENS_DOC = "ai.google.dev/gemini-api/docs/tokens (images)"
GEMINI_MEDIA_RESOLUTION_DOC = "ai.google.dev/gemini-api/docs/media-resolution#token-counts"


@dataclass(frozen=True)
class ImageRule:
    """A provider's published rule for the input tokens one image costs, for the models it names.

    ``kind``:

    * ``tile`` (OpenAI, ``detail: high``): fit in 2048 × 2048, scale the short side down to 768, then
      ``base + tile × (512-px tiles)``;
    * ``patch`` (OpenAI's newer minis): 32-px patches, at most 1536 (a larger image is scaled down to fit,
      each side to a whole number of patches), times ``multiplier``, rounded up;
    * ``anthropic``: scale down until the long side is at most 1568 px and the area at most 1092 × 1092 px
      (the documented ~1,600-token maximum), then ``ceil(width × height / 750)``;
    * ``gemini-tile`` (Gemini 2.x): 258 for an image within 384 × 384, else 258 per 768 × 768 tile;
    * ``per-image``: ``tokens`` per image whatever its size (``exact`` False: a documented maximum).

    ``source`` is where the rule is published and when it was read; ``exact`` is False where the rule gives a
    maximum rather than the count; ``provider`` is whose rule it is (``openai``, ``anthropic``, ``gemini``), what the
    estimate line names (``anthropic rule``) whichever server the model is reached through.
    """

    name: str
    kind: str
    source: str
    base: int = 0
    tile: int = 0
    multiplier: float = 1.0
    tokens_per_image: int = 0
    exact: bool = True
    provider: str = "openai"  # whose rule it is (the estimate line names it: 'anthropic rule')

    def tokens(self, width: int, height: int) -> int:
        """Input tokens of one ``width`` × ``height`` image (pixels) under this rule; ValueError for a size below 1."""
        import math

        if width < 1 or height < 1:
            raise ValueError(f"an image needs a positive size, got {width} × {height}")
        if self.kind == "tile":
            scale = min(1.0, 2048 / max(width, height))
            w, h = width * scale, height * scale
            scale = min(1.0, 768 / min(w, h))
            w, h = w * scale, h * scale
            return self.base + self.tile * math.ceil(w / 512) * math.ceil(h / 512)
        if self.kind == "patch":
            return math.ceil(_patches(width, height) * self.multiplier - 1e-9)
        if self.kind == "anthropic":
            scale = min(1.0, ANTHROPIC_MAX_SIDE / max(width, height),
                        math.sqrt(ANTHROPIC_MAX_PIXELS / (width * height)))
            return math.ceil(round(width * scale) * round(height * scale) / 750)
        if self.kind == "gemini-tile":
            if width <= 384 and height <= 384:
                return 258
            return 258 * math.ceil(width / 768) * math.ceil(height / 768)
        if self.kind == "per-image":
            return self.tokens_per_image
        raise ValueError(f"unknown image rule kind {self.kind!r}")

    def describe(self) -> str:
        """One line: the rule, ``at most`` where it is a maximum, and its source."""
        return f"{self.name} ({self.source})"


#: Anthropic: the long side at most 1568 px; the area at most that of the 1:1 (1092 × 1092) and 9:16 (819 × 1456)
#: rows of the documented table of largest unresized sizes (~1,600 tokens)
ANTHROPIC_MAX_SIDE, ANTHROPIC_MAX_PIXELS = 1568, 1092 * 1092
PATCH_SIZE, PATCH_LIMIT = 32, 1536


def _patches(width: int, height: int) -> int:
    """32-px patches of an image after OpenAI's downscaling to at most :data:`PATCH_LIMIT` patches (the documented
    steps: shrink by √(32² × 1536 / (w × h)), then further so that each side is a whole number of patches)."""
    import math

    raw = math.ceil(width / PATCH_SIZE) * math.ceil(height / PATCH_SIZE)
    if raw <= PATCH_LIMIT:
        return raw
    r = math.sqrt(PATCH_SIZE**2 * PATCH_LIMIT / (width * height))
    w_p, h_p = width * r / PATCH_SIZE, height * r / PATCH_SIZE
    r *= min(math.floor(w_p) / w_p, math.floor(h_p) / h_p)
    return min(PATCH_LIMIT, math.ceil(width * r / PATCH_SIZE - 1e-9) * math.ceil(height * r / PATCH_SIZE - 1e-9))


def _openai_tile(name: str, base: int, tile: int, quoted: str) -> ImageRule:
    return ImageRule(name=f"OpenAI tiles (detail high): {base} + {tile} per 512-px tile", kind="tile", base=base,
                     tile=tile, source=f"{OPENAI_VISION_DOC}, {name} row; as quoted by {quoted} (stored copies), "
                     f"read {IMAGE_RULES_READ}")


def _openai_patch(name: str, multiplier: float) -> ImageRule:
    return ImageRule(name=f"OpenAI 32-px patches (at most {PATCH_LIMIT}) × {multiplier:g}", kind="patch",
                     multiplier=multiplier, source=f"{OPENAI_VISION_DOC}, patch rule, {name} multiplier; as quoted by "
                     f"github.com/xn1cklas/tokenlens/issues/7 and community.openai.com/t/1230130 (stored copies), "
                     f"read {IMAGE_RULES_READ}")


_DATE = r"(-\d{4}-\d{2}-\d{2})?"
_GPT4O_QUOTES = "v2ex.com/t/1044688 (the page's text with its 765- and 1105-token examples) and a64.in's calculator"
_GPT4O_MINI_QUOTES = "github.com/epam/ai-dial-adapter-openai/issues/165 and github.com/autogenhub/autogen/pull/57"
_CLAUDE = (r"claude-(3-haiku|3-sonnet|3-opus|3-5-sonnet|3-5-haiku|3-7-sonnet|sonnet-4|opus-4|opus-4-1|sonnet-4-5|"
           r"haiku-4-5|opus-4-5|sonnet-4-6|opus-4-6)(-\d{8}|-latest)?")
#: (pattern over the model id without its provider prefix, rule), first match wins. Left out on purpose, with why:
#: gpt-4.1 (the docs' patch rule at × 1 and the billed tile rule disagree: community.openai.com/t/1230130);
#: gpt-5-mini and gpt-5-nano (the docs' × 1.62 / × 2.46 and OpenAI's pricing calculator's × 1.2 / × 1.5 disagree:
#: community.openai.com/t/1344040); gpt-5, gpt-5.2, the o-series but o4-mini and gpt-4.5 (no base/tile figures for
#: them in any copy read); Claude models after 4.6 (a higher-resolution tier).
IMAGE_RULES: tuple[tuple[str, ImageRule], ...] = (
    (rf"gpt-4o-mini{_DATE}", _openai_tile("4o-mini", 2833, 5667, _GPT4O_MINI_QUOTES)),
    (rf"gpt-4o{_DATE}", _openai_tile("4o", 85, 170, _GPT4O_QUOTES)),
    (rf"gpt-4\.1-mini{_DATE}", _openai_patch("gpt-4.1-mini", 1.62)),
    (rf"gpt-4\.1-nano{_DATE}", _openai_patch("gpt-4.1-nano", 2.46)),
    (rf"o4-mini{_DATE}", _openai_patch("o4-mini", 1.72)),
    (_CLAUDE,
     ImageRule(name=f"Anthropic: long side ≤ {ANTHROPIC_MAX_SIDE} px, area ≤ 1092 × 1092 px, width × height / 750",
               kind="anthropic", provider="anthropic",
               source=f"{ANTHROPIC_VISION_DOC} (stored copies of docs.anthropic.com/en/docs/vision "
               f"and platform.claude.com/docs/*/build-with-claude/vision), read {IMAGE_RULES_READ}")),
    (r"gemini-2\.(0|5)-[a-z0-9.-]+",
     ImageRule(name="Gemini 2.x: 258 within 384 × 384 px, else 258 per 768 × 768 tile", kind="gemini-tile",
               provider="gemini",
               source=f"{GEMINI_TOKENS_DOC}; as quoted by geminibyexample.com/027-calculate-input-tokens (stored "
               f"copy), read {IMAGE_RULES_READ}")),
    (r"gemini-3(\.\d+)?-[a-z0-9.-]+",
     ImageRule(name="Gemini 3: at most 1120 per image (media resolution high, the default for images)",
               kind="per-image", tokens_per_image=1120, exact=False, provider="gemini",
               source=f"{GEMINI_MEDIA_RESOLUTION_DOC}; as quoted by fastgptplus.com/en/posts/gemini-3-pro-media-"
               f"resolution-parameter (stored copy), read {IMAGE_RULES_READ}")),
)
#: provider prefixes of litellm model strings whose bare model name the rules above are about
_RULE_PREFIXES = ("openai/", "anthropic/", "gemini/", "vertex_ai/")


def image_rule(model: ModelInfo | str) -> ImageRule | None:
    """The published image-token rule of ``model`` (a registry entry or a litellm model string), or None when no rule
    is published for it or its published readings disagree (:data:`IMAGE_RULES`, which says which and why)."""
    import re

    model_id = model.model_id if isinstance(model, ModelInfo) else str(model)
    name = _norm(model_id)
    for prefix in _RULE_PREFIXES:
        if name.startswith(prefix):
            name = name[len(prefix):]
            break
    if "/" in name:  # another provider's route (openrouter/…, azure/…): its billing is not the rule's
        return None
    for pattern, rule in IMAGE_RULES:
        if re.fullmatch(pattern, name):
            return rule
    return None


#: each provider's default rule, for :func:`image_tokens` by provider (the estimate uses :func:`image_rule` per model)
def _named_rule(model: str) -> ImageRule:
    rule = image_rule(model)
    if rule is None:  # pragma: no cover - the table names these models
        raise LookupError(f"no image rule for {model}")
    return rule


_PROVIDER_RULES = {provider: _named_rule(model) for provider, model in
                   (("openai", "gpt-4o"), ("anthropic", "claude-3-7-sonnet"), ("gemini", "gemini-2.0-flash"))}
#: where each provider's image-token rules are published (shown by ``--estimate``)
IMAGE_TOKEN_RULES = {
    "openai": f"{OPENAI_VISION_DOC} (detail high: fit in 2048 × 2048, short side to 768, base + tile per 512-px tile, "
              "per model; or 32-px patches × a per-model multiplier)",
    "anthropic": f"{ANTHROPIC_VISION_DOC} (long side to at most 1568 px, area to at most ~1,600 tokens, tokens = "
                 "width × height / 750)",
    "gemini": f"{GEMINI_TOKENS_DOC} (258 tokens for an image within 384 × 384, else 258 per 768 × 768 tile; Gemini 3: "
              f"{GEMINI_MEDIA_RESOLUTION_DOC})",
}


def image_tokens(width: int, height: int, provider: str) -> int:
    """Input tokens one ``width`` × ``height`` image costs under ``provider``'s base rule (``openai``: gpt-4o's tiles,
    ``anthropic``, ``gemini`` / ``vertex_ai``: Gemini 2.x tiles); any other provider is counted as ``openai``.

    A model's own rule can differ (gpt-4o-mini's tiles cost 33 × gpt-4o's): :func:`image_rule` gives it, and the
    estimate uses that. ValueError for a size below 1.
    """
    rule = _PROVIDER_RULES.get("gemini" if provider == "vertex_ai" else provider, _PROVIDER_RULES["openai"])
    return rule.tokens(width, height)


#: output tokens per frame (three stages, first attempt) for a model the paper did not run
DEFAULT_OUTPUT_TOKENS = 400


def typical_output_tokens(info: ModelInfo) -> tuple[int, str]:
    """Output tokens a frame typically takes (all three stages) and where the figure comes from:
    the paper's Table I for its models, else :data:`DEFAULT_OUTPUT_TOKENS` (about the paper's median)."""
    from lightemma.evaluation.paper import paper_efficiency_rows

    for row in paper_efficiency_rows():
        if row["model"] == info.display_name and row.get("output_tokens"):
            return int(row["output_tokens"]), "the paper's Table I"
    return DEFAULT_OUTPUT_TOKENS, "lightemma's default (about the paper's median)"


def list_models() -> list[dict[str, Any]]:
    """The registry as plain dicts, in table order (paper models, then baselines), each with its ``price``."""
    return [{**m.to_dict(), "price": price(m)} for m in MODELS]


def suggest(name: str, n: int = 3) -> list[str]:
    """Registry names (and litellm model strings) close to a mistyped ``name``, best first."""
    import difflib

    from lightemma._litellm import litellm

    keys = [m.key for m in MODELS]
    found = difflib.get_close_matches(_norm(name), keys, n=n, cutoff=0.6)
    if len(found) < n:
        chat = [k for k, v in litellm.model_cost.items() if isinstance(v, dict) and v.get("mode") == "chat"]
        found += [m for m in difflib.get_close_matches(name.strip(), chat, n=n, cutoff=0.75) if m not in found]
    return found[:n]
