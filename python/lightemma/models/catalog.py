"""The model catalog: the paper's 15 models, the baselines, and any other model string.

Each paper model carries its display name exactly as in the paper's tables,
its family, its generation order within the family (1 = oldest), how it is
reached (``api`` through litellm, or a local ``hf`` checkpoint also servable by
``vllm``), the H100 GPUs the paper used, and its price.

API ids were checked against litellm's bundled price list
(``litellm.model_cost``, litellm 1.106.2). Where that list lacks a paper model
the entry carries the provider's list price itself, with where and when it was
read (``price_source``, ``price_read``); litellm's price wins whenever it has one
(:mod:`lightemma.models.prices`).

Reasoning models (GPT-5.x, Gemini 2.5 and later) spend output tokens on hidden
reasoning before the answer, and providers count those against the output limit:
with the paper's 512 tokens per stage they can spend everything on reasoning and
return no answer. Their entries carry ``reasoning_budget``, output tokens sent on top
of ``--max-tokens`` so that the answer keeps its own room (the reasoning effort stays
the provider's default, as the paper ran them). Claude models reason only with
extended thinking, which lightemma does not request. A model outside the catalog
that litellm's list marks as reasoning gets :data:`DEFAULT_REASONING_BUDGET`
(:func:`lightemma.models.prices.reasoning_budget`).

Anything not in the catalog is taken as a litellm model string
(``anthropic/…``, ``gemini/…``, ``openai/NAME`` with ``--api-base``, …).
``lightemma models`` prints the catalog. Prices: :mod:`lightemma.models.prices`; image and output token rules:
:mod:`lightemma.models.tokens`; model-name matching: :mod:`lightemma.models.names`; the paper's tables:
:mod:`lightemma.models.paper`.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

from lightemma.errors import UserError

ANTHROPIC_PRICES = "docs.anthropic.com/en/docs/about-claude/pricing (stored copy)"
GOOGLE_PRICES = "ai.google.dev/gemini-api/docs/pricing (as quoted by morphllm.com/gemini-api-pricing, stored copy)"
PRICE_READ = "2026-11-22"
# Batch prices: 50 % of the interactive price for input and output tokens at all three providers.
OPENAI_BATCH_PRICES = (
    "platform.openai.com/docs/guides/batch (50 % of the synchronous price; per model in litellm's list)"
)
ANTHROPIC_BATCH_PRICES = (
    "docs.anthropic.com/en/docs/build-with-claude/batch-processing#pricing (50 % of standard prices)"
)
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
    return ModelInfo(
        key=key, display_name=display, family=family, generation=gen, model_id=model_id, backend="api", **kw
    )


def _local(key: str, display: str, family: str, gen: int, checkpoint: str, gpus: int) -> ModelInfo:
    return ModelInfo(
        key=key, display_name=display, family=family, generation=gen, model_id=checkpoint, backend="hf", gpus=gpus
    )


_REASONS = dict(reasoning=True, reasoning_budget=DEFAULT_REASONING_BUDGET)
# Sonnet 3.7 and 4: $3 input, $15 output, cache hits $0.30, 5-minute cache writes $3.75 per million tokens
_ANTHROPIC_SONNET = dict(
    input_usd_per_mtok=3.0,
    output_usd_per_mtok=15.0,
    cache_read_usd_per_mtok=0.30,
    cache_write_usd_per_mtok=3.75,
    price_source=ANTHROPIC_PRICES,
    price_read=PRICE_READ,
    batch_input_usd_per_mtok=1.5,
    batch_output_usd_per_mtok=7.5,
    batch_price_source=ANTHROPIC_BATCH_PRICES,
)

PAPER_MODELS: tuple[ModelInfo, ...] = (
    _api("gpt-4o", "GPT-4o", "GPT", 1, "gpt-4o"),
    _api("gpt-5.0", "GPT-5.0", "GPT", 2, "gpt-5", supports_temperature=False, **_REASONS),
    _api("gpt-5.2", "GPT-5.2", "GPT", 3, "gpt-5.2", supports_temperature=False, **_REASONS),
    _api(
        "claude-3.7-sonnet",
        "Claude-3.7-Sonnet",
        "Claude",
        1,
        "anthropic/claude-3-7-sonnet-20250219",
        **_ANTHROPIC_SONNET,
    ),
    _api(
        "claude-4.0-sonnet", "Claude-4.0-Sonnet", "Claude", 2, "anthropic/claude-sonnet-4-20250514", **_ANTHROPIC_SONNET
    ),
    _api("claude-4.6-sonnet", "Claude-4.6-Sonnet", "Claude", 3, "anthropic/claude-sonnet-4-6"),
    _api(
        "gemini-2.0-flash",
        "Gemini-2.0-Flash",
        "Gemini",
        1,
        "gemini/gemini-2.0-flash",
        input_usd_per_mtok=0.10,
        output_usd_per_mtok=0.40,
        price_source=GOOGLE_PRICES,
        price_read=PRICE_READ,
        batch_input_usd_per_mtok=0.05,
        batch_output_usd_per_mtok=0.20,
        batch_price_source=GOOGLE_BATCH_PRICES,
    ),
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
    ModelInfo(
        key=f"baseline:{kind}",
        display_name=f"Baseline ({label})",
        family="baseline",
        generation=0,
        model_id=f"baseline:{kind}",
        backend="baseline",
        in_paper=False,
    )
    for kind, label in (
        ("constant", "constant actions"),
        ("cv", "constant velocity"),
        ("oracle", "oracle actions"),
        ("ego", "ego status"),
    )
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
    return ModelInfo(
        key=name, display_name=name, family="other", generation=0, model_id=name, backend="api", in_paper=False
    )


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


def suggest(name: str, n: int = 3) -> list[str]:
    """Registry names (and litellm model strings) close to a mistyped ``name``, best first."""
    import difflib

    from lightemma._litellm import litellm  # seconds to import: only for a model name not in the catalog

    keys = [m.key for m in MODELS]
    found = difflib.get_close_matches(_norm(name), keys, n=n, cutoff=0.6)
    if len(found) < n:
        chat = [k for k, v in litellm.model_cost.items() if isinstance(v, dict) and v.get("mode") == "chat"]
        found += [m for m in difflib.get_close_matches(name.strip(), chat, n=n, cutoff=0.75) if m not in found]
    return found[:n]
