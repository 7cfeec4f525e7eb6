"""Prices: what a model's tokens cost, interactively and through the batch APIs, and where each figure comes from.

litellm's bundled price list wins whenever it has the model; else the catalog's own provider price
(:mod:`lightemma.models.catalog`, with its source and the date it was read); else unknown. Batch prices
(``lightemma run --batch``, :func:`batch_price`) come from litellm's bundled ``*_cost_per_token_batches`` where it has
them, else from the catalog's own entries (with their source), else the list price at the providers' 50 % batch
discount. The bundled list is read as a file, without importing litellm (:func:`bundled_price_list`).
"""

from __future__ import annotations

import functools
import importlib.util
import json
import math
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lightemma.models.catalog import (
    ANTHROPIC_BATCH_PRICES,
    BATCH_DISCOUNT,
    DEFAULT_REASONING_BUDGET,
    GOOGLE_BATCH_PRICES,
    MODELS,
    OPENAI_BATCH_PRICES,
    PRICE_READ,
    ModelInfo,
    _norm,
    lookup,
)

_PRICE_LIST = "model_prices_and_context_window_backup.json"  # the list litellm loads with LITELLM_LOCAL_MODEL_COST_MAP
MAX_USD_PER_MTOK = 1e6  # a price beyond this (USD per million tokens) is no price: the bound of --price too

_PRICE_FIELDS = ("input_usd_per_mtok", "output_usd_per_mtok", "cache_read_usd_per_mtok", "cache_write_usd_per_mtok")


@dataclass(frozen=True)
class Price(Mapping[str, Any]):
    """What a model's tokens cost: USD per million input / output / cache-read / cache-write tokens (None: unknown),
    where the figures come from (``source``), and for a batch-API price (``batch``) the ``discount`` on the input
    price (the batch input price / the interactive one; None when unknown).

    Validated once, here: each price None or a number 0..:data:`MAX_USD_PER_MTOK`, input and output both known or
    both unknown, ``source`` non-empty, a discount only on a batch price; else :class:`ValueError` naming the field.
    Read as the plain dict it is recorded as (``price["source"]``, :meth:`to_dict`: the keys of :data:`_PRICE_FIELDS`,
    ``source``, and ``discount`` for a batch price), which is what :func:`list_models` and the manifests hold.
    """

    input_usd_per_mtok: float | None
    output_usd_per_mtok: float | None
    cache_read_usd_per_mtok: float | None
    cache_write_usd_per_mtok: float | None
    source: str
    batch: bool = False
    discount: float | None = None

    def __post_init__(self) -> None:
        for name in _PRICE_FIELDS:
            value = getattr(self, name)
            if value is None:
                continue
            if (
                isinstance(value, bool)
                or not isinstance(value, (int, float))
                or not math.isfinite(value)
                or not 0 <= value <= MAX_USD_PER_MTOK
            ):
                raise ValueError(
                    f"price {name} must be a number from 0 to {MAX_USD_PER_MTOK:g} or None, got {value!r} "
                    f"({self.source})"
                )
        if (self.input_usd_per_mtok is None) != (self.output_usd_per_mtok is None):
            raise ValueError(f"a price needs both its input and output prices or neither ({self.source})")
        if not isinstance(self.source, str) or not self.source:
            raise ValueError(f"a price needs its source, got {self.source!r}")
        if self.discount is not None and (
            not self.batch
            or isinstance(self.discount, bool)
            or not isinstance(self.discount, (int, float))
            or not math.isfinite(self.discount)
            or self.discount < 0
        ):
            raise ValueError(
                f"a discount is a number of at least 0 on a batch price, got {self.discount!r} ({self.source})"
            )

    @classmethod
    def unknown(cls, source: str, *, batch: bool = False) -> Price:
        """No known price (costs are recorded as null), saying why in ``source``."""
        return cls(None, None, None, None, source, batch=batch)

    @property
    def known(self) -> bool:
        """Whether input and output tokens have a price."""
        return self.input_usd_per_mtok is not None

    def to_dict(self) -> dict[str, Any]:
        """The price as recorded: USD per million tokens by kind, ``source``, and ``discount`` for a batch price."""
        out: dict[str, Any] = {name: getattr(self, name) for name in _PRICE_FIELDS}
        out["source"] = self.source
        if self.batch:
            out["discount"] = self.discount
        return out

    def __getitem__(self, key: str) -> Any:
        if key in _PRICE_FIELDS or key == "source" or (key == "discount" and self.batch):
            return getattr(self, key)
        raise KeyError(key)

    def __iter__(self) -> Iterator[str]:
        return iter(self.to_dict())

    def __len__(self) -> int:
        return len(_PRICE_FIELDS) + 1 + self.batch


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

    from lightemma._litellm import litellm  # seconds to import: only where the bundled file is missing

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


def price(info: ModelInfo) -> Price:
    """The price lightemma uses for ``info``: USD per million input/output tokens and where it comes from.

    litellm's bundled price list wins when it has the model; else the registry's own provider price
    (with its source and the date it was read); else unknown (``None`` prices: costs are recorded as null).
    Local models and baselines cost nothing per token (``source`` says so).
    """
    if info.backend in ("hf", "vllm", "baseline"):
        return Price.unknown("no model" if info.backend == "baseline" else "local model: GPUs, not tokens")
    entry = _litellm_entry(info.model_id)
    if entry.get("input_cost_per_token") is not None and entry.get("output_cost_per_token") is not None:

        def per_mtok(key: str) -> float | None:
            return float(entry[key]) * 1e6 if entry.get(key) is not None else None

        return Price(
            per_mtok("input_cost_per_token"),
            per_mtok("output_cost_per_token"),
            per_mtok("cache_read_input_token_cost"),
            per_mtok("cache_creation_input_token_cost"),
            f"litellm {_litellm_version()} bundled price list",
        )
    if info.input_usd_per_mtok is not None and info.output_usd_per_mtok is not None:
        return Price(
            info.input_usd_per_mtok,
            info.output_usd_per_mtok,
            info.cache_read_usd_per_mtok,
            info.cache_write_usd_per_mtok,
            f"{info.price_source}, read {info.price_read}",
        )
    return Price.unknown("unknown (costs recorded as null)")


def run_price(
    info: ModelInfo, *, batch: bool = False, given: Sequence[float] | None = None, served_from: str | None = None
) -> Price:
    """The price a run bills its calls at, shaped like :func:`price`: ``given`` (``--price``: USD per million input /
    output tokens, for every call of the run, batched or not; cached and cache-write input tokens at the input
    price), else unknown when the model is
    served from another ``--api-base`` (``served_from``: not the provider's list price), else :func:`batch_price`
    (``batch``) or :func:`price`. :class:`~lightemma.backends.api.APIBackend` and
    :class:`~lightemma.backends.batch.BatchBackend` price calls this way, and ``--estimate`` / ``--max-cost`` with them."""
    if given is not None:  # every input token at the input price: cached and cache-write ones too
        return Price(
            float(given[0]),
            float(given[1]),
            float(given[0]),
            float(given[0]),
            f"--price {float(given[0]):g} {float(given[1]):g} (USD per million input / output tokens)",
        )
    if served_from is not None:
        return Price.unknown(f"none: served from {served_from}")
    return batch_price(info) if batch else price(info)


def price_per_token(info: ModelInfo) -> tuple[float, float] | None:
    """(input, output) USD per token: litellm's bundled price when it has one, else the registry's."""
    if info.backend != "api":
        return None
    found = price(info)
    if found.input_usd_per_mtok is None or found.output_usd_per_mtok is None:
        return None
    return found.input_usd_per_mtok / 1e6, found.output_usd_per_mtok / 1e6


def cache_price_per_token(info: ModelInfo) -> tuple[float | None, float | None]:
    """(cache read, cache write) USD per token from the same source as :func:`price_per_token`; None where unknown."""
    if info.backend != "api":
        return None, None
    found = price(info)
    read, write = found.cache_read_usd_per_mtok, found.cache_write_usd_per_mtok
    return (None if read is None else read / 1e6), (None if write is None else write / 1e6)


def batch_price(info: ModelInfo) -> Price:
    """The batch-API price of ``info`` (``lightemma run --batch``), shaped like :func:`price`.

    litellm's bundled ``*_cost_per_token_batches`` when it has them; else the registry's own batch prices
    (with their source); else the interactive price at the providers' batch discount
    (:data:`BATCH_DISCOUNT`, 50 % at OpenAI, Anthropic and Google). Cache-read and cache-write prices are
    the interactive ones at the same discount (Anthropic: batch and cache discounts stack). Unknown
    prices stay None.
    """
    base = price(info)
    if info.backend != "api" or base.input_usd_per_mtok is None or base.output_usd_per_mtok is None:
        return Price(
            base.input_usd_per_mtok,
            base.output_usd_per_mtok,
            base.cache_read_usd_per_mtok,
            base.cache_write_usd_per_mtok,
            base.source,
            batch=True,
        )
    entry = _litellm_entry(info.model_id)
    if entry.get("input_cost_per_token_batches") is not None and entry.get("output_cost_per_token_batches") is not None:
        pin, pout = (
            float(entry["input_cost_per_token_batches"]) * 1e6,
            float(entry["output_cost_per_token_batches"]) * 1e6,
        )
        source = f"litellm {_litellm_version()} bundled price list (batches)"
    elif info.batch_input_usd_per_mtok is not None and info.batch_output_usd_per_mtok is not None:
        pin, pout = info.batch_input_usd_per_mtok, info.batch_output_usd_per_mtok
        source = f"{info.batch_price_source}, read {info.price_read or PRICE_READ}"
    else:
        pin, pout = base.input_usd_per_mtok * BATCH_DISCOUNT, base.output_usd_per_mtok * BATCH_DISCOUNT
        source = f"{base.source} at the batch discount ({BATCH_DISCOUNT:.0%}: {_batch_source(info)})"
    discount = pin / base.input_usd_per_mtok if base.input_usd_per_mtok else BATCH_DISCOUNT

    def scaled(value: float | None) -> float | None:
        return None if value is None else value * discount

    return Price(
        pin,
        pout,
        scaled(base.cache_read_usd_per_mtok),
        scaled(base.cache_write_usd_per_mtok),
        source,
        batch=True,
        discount=discount,
    )


def _batch_source(info: ModelInfo) -> str:
    model = _norm(info.model_id)
    if model.startswith("anthropic/") or "claude" in model:
        return ANTHROPIC_BATCH_PRICES
    if model.startswith(("gemini/", "vertex_ai/")):
        return GOOGLE_BATCH_PRICES
    return OPENAI_BATCH_PRICES


def list_models() -> list[dict[str, Any]]:
    """The registry as plain dicts, in table order (paper models, then baselines), each with its ``price``."""
    return [{**m.to_dict(), "price": price(m).to_dict()} for m in MODELS]
