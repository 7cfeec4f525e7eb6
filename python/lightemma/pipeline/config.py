"""A run's settings as one typed, frozen value: :class:`RunConfig`, validated once, here.

:func:`lightemma.run` builds a :class:`RunConfig` from its keyword arguments (:meth:`RunConfig.of`) or takes one
(``lightemma.run(config=...)``); :func:`lightemma.resume` reads one from the run's manifest
(:meth:`RunConfig.from_manifest`). :meth:`RunConfig.to_manifest` gives the manifest's ``config`` block exactly as
lightemma has always written it (same keys, same order, same values), so a run directory written before this
module existed resumes as before.

Every setting's kind, whether it may be null, whether a manifest must hold it, and its range are one row of
:data:`SETTINGS` (the dataset request's of :data:`DATASET_SETTINGS`; local-model options of
:data:`BACKEND_OPTION_SETTINGS`). The command line reads the same rows for its checks (``lightemma run --help``
names the defaults); only its messages differ: a library error names the parameter (``concurrency must be at least
1, got 0``, :class:`InvalidSetting`), the CLI translates the parameter to its flag (``--concurrency``).
Why the ranges: beyond them a run would wait without end (a rate of 1e-300 per minute, a 1e-300 s deadline) or
retry without end (10**9 attempts) — docs/run.md.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from types import MappingProxyType
from typing import Any

from lightemma._text import unicode_clean
from lightemma.backends.api import MAX_PRICE
from lightemma.backends.retry import redact_url
from lightemma.errors import UserError
from lightemma.prompts import DEFAULT_PROMPT_SET

DEFAULT_CACHE = "cache.sqlite"  # the response cache's default place, relative to the output directory


@dataclass(frozen=True, slots=True)
class Setting:
    """One row of the settings table.

    ``kind``: ``text``, ``int`` (a whole number, no bool), ``number`` (int or float, no bool, finite), ``bool``,
    ``object`` (a mapping) or ``list``. ``minimum`` (``exclusive``: above, else at least) holds for ``int`` /
    ``number``; ``span`` is the inclusive range (low, high) beyond the minimum's kind. ``required``: a manifest's
    config without it is refused. ``absent``: the value a manifest written before the setting existed means.
    ``param``: the keyword of :func:`lightemma.run` (and attribute path ``group.name`` on :class:`RunConfig`).
    """

    key: str
    kind: str
    nullable: bool = True
    required: bool = False
    minimum: float | None = None
    exclusive: bool = False
    span: tuple[float, float] | None = None
    absent: Any = None
    group: str | None = None  # None: a field of RunConfig itself; else the group's attribute on RunConfig
    attr: str | None = None  # the attribute in the group (default: key)
    param: str | None = None  # the run() keyword (default: key)

    @property
    def name(self) -> str:
        return self.param or self.key


#: the manifest's ``config`` block, row by row, in the order it is written
SETTINGS: tuple[Setting, ...] = (
    Setting("model", "text", nullable=False, required=True),
    Setting("backend", "text", required=True),
    Setting("api_base", "text", required=True, group="api"),
    Setting("api_key_env", "text", group="api"),
    Setting("price", "list", group="api"),
    Setting("gpus", "int", minimum=0, group="api"),
    Setting("concurrency", "int", nullable=False, required=True, minimum=1, span=(1, 4096)),
    Setting("temperature", "number", nullable=False, required=True, minimum=0, span=(0.0, 100.0), group="prompting"),
    Setting("max_tokens", "int", nullable=False, required=True, minimum=1, span=(1, 1_000_000), group="prompting"),
    Setting("reask", "text", nullable=False, required=True, group="prompting"),
    Setting("max_attempts", "int", nullable=False, required=True, minimum=1, span=(1, 100), group="prompting"),
    Setting("integrate_method", "text", nullable=False, required=True, group="prompting"),
    Setting("speed_range", "list", group="prompting"),
    Setting("max_abs_curvature", "number", minimum=0, group="prompting"),
    Setting("chain", "text", absent="independent", group="prompting"),
    Setting("answer_format", "text", absent="text", group="prompting"),
    Setting("inputs", "text", absent="full", group="prompting"),
    Setting("prompt_set", "text", nullable=False, required=True, group="prompting"),
    # K independent chains per frame (--samples; docs/run.md#k-samples); written only when K > 1, so a K = 1 run's
    # manifest is the one lightemma always wrote
    Setting("samples", "int", nullable=False, minimum=1, span=(1, 64), absent=1, group="prompting"),
    Setting("timeout", "number", nullable=False, required=True, minimum=0, exclusive=True, span=(0.001, 86_400.0)),
    Setting("max_retries", "int", nullable=False, required=True, minimum=0, span=(0, 100), group="api"),
    Setting("backoff_base", "number", nullable=False, required=True, minimum=0, span=(0.0, 600.0), group="api"),
    Setting("backoff_cap", "number", nullable=False, required=True, minimum=0, span=(0.0, 3600.0), group="api"),
    Setting("rpm", "number", required=True, minimum=0, exclusive=True, span=(1.0, 1e9), group="api"),
    Setting("tpm", "number", required=True, minimum=0, exclusive=True, span=(10.0, 1e12), group="api"),
    Setting("transport", "text", absent="litellm", group="api"),
    Setting("backend_options", "object", absent=MappingProxyType({}), group="local"),
    Setting("cache", "text", group="api"),
    Setting("replicas", "int", minimum=1, span=(1, 1024), absent=1, group="local"),
    # checked by the resume trust policy (lightemma.pipeline.trust), which names what a run directory may not choose
    Setting("ray_address", "text", group="local"),
    Setting("gpus_per_replica", "number", minimum=0, group="local"),
    Setting("batch", "bool", absent=False, group="batch", attr="enabled"),
    Setting("batch_poll", "number", minimum=0, exclusive=True, span=(0.01, 3600.0), group="batch", attr="poll"),
    Setting("max_cost_cents", "number", minimum=0, exclusive=True, span=(0.0, 1e9)),
)

#: the manifest's ``config.dataset`` block (the request as given: what a resume loads again)
DATASET_SETTINGS: tuple[Setting, ...] = (
    Setting("dataroot", "text", group="dataset"),
    Setting("version", "text", group="dataset"),
    Setting("split", "text", group="dataset"),
    Setting("scenes", "list", group="dataset"),
    Setting("window", "text", absent="reference", group="dataset"),
    Setting("limit", "int", minimum=1, group="dataset"),
    Setting("on_bad_record", "text", absent="skip", group="dataset"),
    Setting("sample", "int", minimum=1, group="dataset"),  # the manifest's sample.n
    Setting("sample_seed", "int", group="dataset"),  # the manifest's sample.seed
)

#: local-model options (``backend_options`` of the hf / vllm backends) the command line takes as flags
BACKEND_OPTION_SETTINGS: tuple[Setting, ...] = (
    Setting("batch_size", "int", minimum=1, group="local"),
    Setting("max_pixels", "int", minimum=1, group="local"),
    Setting("tensor_parallel_size", "int", minimum=1, group="local"),
    Setting("pipeline_parallel_size", "int", minimum=1, group="local"),
    Setting("gpu_memory_utilization", "number", minimum=0, exclusive=True, group="local"),
)

_BY_NAME: dict[str, Setting] = {s.name: s for s in (*SETTINGS, *DATASET_SETTINGS, *BACKEND_OPTION_SETTINGS)}
_KINDS = {
    "text": "text",
    "int": "a whole number",
    "number": "a finite number",
    "object": "an object",
    "list": "a list",
    "bool": "true or false",
}


def setting(name: str) -> Setting | None:
    """The row of parameter ``name`` (None for ``model``'s companions without one: ``name``)."""
    return _BY_NAME.get(name)


def short_repr(value: Any, limit: int = 60) -> str:
    """``repr(value)`` cut to ``limit`` characters: a value shown in a one-line message."""
    if isinstance(value, int) and not isinstance(value, bool) and value.bit_length() > 200:
        return f"a whole number of {len(str(value)) if value.bit_length() < 13_000 else 'thousands of'} digits"
    try:
        text = repr(value)
    except (ValueError, RecursionError):  # a number of over 4,300 digits inside, or nested beyond the stack
        return f"a {type(value).__name__} that cannot be shown"
    return text if len(text) <= limit else text[: limit - 1] + "…"


def shown(value: Any) -> str:
    """A given value as a message shows it: a number as ``{:g}`` (``1e+09``, ``nan``), anything else as its repr."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        try:
            return f"{value:g}"
        except OverflowError:
            return short_repr(value)
    return short_repr(value)


def finite(value: Any) -> bool:
    """A number that is no bool, and finite (an integer too large for a float is not)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return False
    try:
        return math.isfinite(value)
    except OverflowError:  # an int beyond a float's range
        return False


def problem(row: Setting, value: Any) -> str | None:
    """What is wrong with ``value`` for ``row`` (None when nothing is): ``type``, ``nul``, ``min`` (below the
    minimum), ``nan``, ``-inf``, ``inf`` or ``span`` (outside the range). The one check of every setting."""
    if value is None:
        return None if row.nullable else "type"
    types: tuple[type, ...] = {
        "text": (str,),
        "int": (int,),
        "number": (int, float),
        "object": (Mapping,),
        "list": (list, tuple),
        "bool": (bool,),
    }[row.kind]
    of_kind = isinstance(value, types) and (row.kind == "bool" or not isinstance(value, bool))
    if not of_kind:
        return "type"
    if row.kind == "text":
        return "nul" if "\x00" in value else None
    if row.kind not in ("int", "number"):
        return None
    if row.kind == "number" and not finite(value):
        if isinstance(value, int):  # beyond a float's range
            return "inf" if value > 0 else "-inf"
        return "nan" if value != value else ("inf" if value > 0 else "-inf")
    low = row.minimum
    if low is not None and (value <= low if row.exclusive else value < low):
        return "min"
    if row.span is not None and not row.span[0] <= value <= row.span[1]:
        return "span"
    return None


def requirement(row: Setting, what: str) -> str:
    """The requirement ``what`` (a :func:`problem`) broke, as a parameter's or flag's message says it (``at least 1``,
    ``greater than 0``, ``between 1 and 4096``, ``a finite number``, ``a whole number``, …)."""
    if what in ("min", "nan", "-inf"):
        return f"{'greater than' if row.exclusive else 'at least'} {row.minimum:g}"
    if what == "inf":
        return "a finite number"
    if what == "span":
        assert row.span is not None
        return f"between {row.span[0]:g} and {row.span[1]:g}"
    if what == "nul":
        return "text without NUL characters"
    return _KINDS[row.kind]


def manifest_requirement(row: Setting, what: str) -> str:
    """The same, as a refused manifest says it (``the manifest's config.timeout is -1, not a number greater than
    0``)."""
    if what == "span":
        return requirement(row, what)
    if what == "nul":
        return "text without NUL characters"
    if what == "min" and row.kind == "number":
        return "a number greater than 0" if row.exclusive else "a number of at least 0"
    return _KINDS[row.kind]


def span_text(name: str) -> str:
    """The range of parameter ``name`` as help texts show it (``1..4096``, ``> 0``), or ``""``."""
    row = _BY_NAME[name]
    if row.span is not None:
        return f"{row.span[0]:g}..{row.span[1]:g}"
    if row.minimum is not None:
        return f"{'>' if row.exclusive else '≥'} {row.minimum:g}"
    return ""


def default(name: str) -> Any:
    """The default of parameter ``name`` (the value :meth:`RunConfig.of` takes when it is not given)."""
    row = _BY_NAME[name]
    if row.group is None:
        owner: Any = RunConfig
    else:
        owner = {
            "dataset": DatasetSettings,
            "prompting": PromptingSettings,
            "api": ApiSettings,
            "local": LocalSettings,
            "batch": BatchSettings,
        }[row.group]
    found = {f.name: f for f in fields(owner)}[row.attr or row.key]
    return found.default_factory() if callable(found.default_factory) else found.default


class InvalidSetting(UserError, ValueError):
    """A run setting out of its kind or range: ``parameter`` (the :func:`lightemma.run` keyword), ``value`` and
    ``requirement`` (``at least 1``, …). The message names the parameter; the CLI names the flag instead."""

    def __init__(self, parameter: str, value: Any, requirement: str) -> None:
        super().__init__(f"{parameter} must be {requirement}, got {shown(value)}")
        self.parameter, self.value, self.requirement = parameter, value, requirement


def check(name: str, value: Any) -> None:
    """Refuse ``value`` for parameter ``name`` with :class:`InvalidSetting` (its row of the table)."""
    row = _BY_NAME[name]
    what = problem(row, value)
    if what is not None:
        raise InvalidSetting(row.name, value, requirement(row, what))


def _pair(name: str, value: Any) -> None:
    """``speed_range`` (low < high, both finite) and ``price`` (input, output USD per million, each 0..MAX_PRICE)."""
    if value is None:
        return
    if name == "speed_range":
        if not (len(value) == 2 and all(map(finite, value)) and value[0] < value[1]):
            raise InvalidSetting(name, list(value), "two finite numbers (low, high) with low < high")
        return

    if not (len(value) == 2 and all(finite(x) and 0 <= x <= MAX_PRICE for x in value)):
        raise InvalidSetting(
            name, list(value), f"two numbers (input, output USD per million tokens), each 0..{MAX_PRICE:g}"
        )


def _frozen_map(value: Any) -> Any:
    return MappingProxyType(dict(value)) if isinstance(value, Mapping) else value


def _check_group(group: Any, rows: Sequence[Setting]) -> None:
    for row in rows:
        if row.group == group.GROUP:
            check(row.name, getattr(group, row.attr or row.key))


@dataclass(frozen=True, slots=True)
class DatasetSettings:
    """Which frames: loaded from ``dataroot`` (absolute) / ``version`` / ``split`` or ``scenes`` / ``window``
    (:func:`lightemma.load_frames`), then ``limit`` (the first N) or ``sample`` (N spread over the scenes, seeded
    by ``sample_seed``). Without a ``dataroot``, the frames are passed in memory (``frames=...``)."""

    GROUP = "dataset"
    dataroot: str | None = None
    version: str | None = "v1.0-test"
    split: str | None = None
    scenes: tuple[str, ...] | None = None
    window: str | None = "reference"
    limit: int | None = None
    on_bad_record: str | None = "skip"
    sample: int | None = None
    sample_seed: int | None = 0

    def __post_init__(self) -> None:
        _check_group(self, DATASET_SETTINGS)
        if self.scenes is not None:
            if not all(isinstance(s, str) for s in self.scenes):
                raise InvalidSetting("scenes", list(self.scenes), "a list of scene names")
            object.__setattr__(self, "scenes", tuple(self.scenes))

    def to_manifest(self) -> dict[str, Any]:
        """The manifest's ``config.dataset``."""
        return {
            "dataroot": self.dataroot,
            "version": self.version if self.dataroot else None,
            "split": self.split,
            "scenes": list(self.scenes) if self.scenes else None,
            "window": self.window,
            "limit": self.limit,
            "on_bad_record": self.on_bad_record,
            "sample": {"n": self.sample, "seed": self.sample_seed} if self.sample is not None else None,
        }


@dataclass(frozen=True, slots=True)
class PromptingSettings:
    """What the model is asked and how its answers are read: sampling ``temperature``, ``max_tokens`` per stage,
    ``reask`` / ``max_attempts`` (docs/definitions.md#re-asks), ``integrate_method`` (#integration), the parser's
    plausibility limits ``speed_range`` (m/s) and ``max_abs_curvature`` (1/m; None: none), the request variant
    (``chain``, ``answer_format``, ``inputs``), the ``prompt_set`` (a shipped name or a JSON file's path) and
    ``samples``: K independent chains per frame (1..64; docs/run.md#k-samples)."""

    GROUP = "prompting"
    temperature: float = 0.0
    max_tokens: int = 512
    reask: str = "actions"
    max_attempts: int = 5
    integrate_method: str = "euler"
    speed_range: tuple[float, float] | None = (-10.0, 50.0)
    max_abs_curvature: float | None = 1.0
    chain: str = "independent"
    answer_format: str = "text"
    inputs: str = "full"
    prompt_set: str = DEFAULT_PROMPT_SET
    samples: int = 1  # K independent chains per frame (--samples)

    def __post_init__(self) -> None:
        _check_group(self, SETTINGS)
        _pair("speed_range", self.speed_range)
        if self.speed_range is not None:
            object.__setattr__(self, "speed_range", tuple(self.speed_range))


@dataclass(frozen=True, slots=True)
class ApiSettings:
    """How a provider's API is called: ``api_base`` (the endpoint as given, credentials and all; recorded without
    them, and a resume is given it again), ``api_key_env``, ``price`` (USD per million input / output tokens) and
    ``gpus`` of a model served from ``api_base``, retries (``max_retries``, ``backoff_base`` / ``backoff_cap`` seconds),
    client-side limits ``rpm`` / ``tpm``, ``transport`` (``litellm`` or ``direct``) and the response ``cache``
    (relative to the output directory, or absolute)."""

    GROUP = "api"
    api_base: str | None = field(default=None, repr=False)  # may carry credentials: never shown
    api_key_env: str | None = None
    price: tuple[float, float] | None = None
    gpus: int | None = None
    max_retries: int = 6
    backoff_base: float = 1.0
    backoff_cap: float = 60.0
    rpm: float | None = None
    tpm: float | None = None
    transport: str | None = "litellm"
    cache: str | None = None

    def __post_init__(self) -> None:
        _check_group(self, SETTINGS)
        _pair("price", self.price)
        if self.price is not None:
            object.__setattr__(self, "price", tuple(self.price))


@dataclass(frozen=True, slots=True)
class LocalSettings:
    """Where a local model (hf, vllm) runs: ``backend_options`` (the backend's own, recorded), ``replicas`` over
    Ray (``ray_address``: a cluster to join; ``gpus_per_replica``)."""

    GROUP = "local"
    backend_options: Mapping[str, Any] = field(default_factory=lambda: MappingProxyType({}), hash=False)
    replicas: int | None = 1
    ray_address: str | None = None
    gpus_per_replica: float | None = None

    def __post_init__(self) -> None:
        options = {} if self.backend_options is None else self.backend_options
        for row in SETTINGS:  # ray_address is the trust policy's to check in a manifest (a run's, given again here)
            if row.group == "local" and row.key != "ray_address":
                check(row.name, options if row.key == "backend_options" else getattr(self, row.key))
        if "api_key" in options:
            raise UserError(
                "backend_options are recorded in the run manifest, so they cannot carry an api_key; "
                "set the provider's environment variable instead"
            )
        for row in BACKEND_OPTION_SETTINGS:  # a number out of range (other kinds are the backend's to refuse)
            value = options.get(row.key)
            if finite(value) and problem(row, value) is not None:
                check(row.name, value)
        object.__setattr__(self, "backend_options", _frozen_map(options))


@dataclass(frozen=True, slots=True)
class BatchSettings:
    """Through the provider's batch interface (``enabled``), first polled after ``poll`` seconds."""

    GROUP = "batch"
    enabled: bool = False
    poll: float | None = 30.0

    def __post_init__(self) -> None:
        _check_group(self, SETTINGS)


def _check_name(name: str | None) -> None:
    if name is not None and (
        not isinstance(name, str)
        or not name.strip()
        or len(name) > 80
        or any(ord(ch) < 32 for ch in name)
        or unicode_clean(name) != name
    ):  # bytes that are not UTF-8 (a Latin-1 terminal)
        raise InvalidSetting("name", name, "1 to 80 printable characters of UTF-8 text")


@dataclass(frozen=True, slots=True)
class RunConfig:
    """Every setting of a run, validated when built (:class:`InvalidSetting` naming the parameter, or a
    :class:`~lightemma.errors.UserError`); frozen. Build it with :meth:`of` from :func:`lightemma.run`'s keywords,
    or field by field; :meth:`replace` gives a changed copy, validated again.

    ``model``: a registry name, litellm model string or ``baseline:*``; ``backend``: api, hf, vllm or baseline
    (None: chosen from the model); ``concurrency``: frames in flight; ``timeout``: seconds a call (or a local batch)
    may take; ``max_cost_cents``: the spending limit in US cents (None: none); ``name``: the run's name in tables.
    """

    model: str
    backend: str | None = None
    concurrency: int = 16
    timeout: float = 120.0
    max_cost_cents: float | None = None
    name: str | None = None
    dataset: DatasetSettings = field(default_factory=DatasetSettings)
    prompting: PromptingSettings = field(default_factory=PromptingSettings)
    api: ApiSettings = field(default_factory=ApiSettings)
    local: LocalSettings = field(default_factory=LocalSettings)
    batch: BatchSettings = field(default_factory=BatchSettings)

    def __post_init__(self) -> None:
        for row in SETTINGS:
            if row.group is None:
                check(row.name, getattr(self, row.key))
        _check_name(self.name)
        for name, kind in (
            ("dataset", DatasetSettings),
            ("prompting", PromptingSettings),
            ("api", ApiSettings),
            ("local", LocalSettings),
            ("batch", BatchSettings),
        ):
            if not isinstance(getattr(self, name), kind):
                raise InvalidSetting(name, getattr(self, name), f"a {kind.__name__}")

    # -- building ------------------------------------------------------------------------------------------------

    @classmethod
    def of(cls, model: str, **keywords: Any) -> RunConfig:
        """The config :func:`lightemma.run` builds from its keywords (every setting's keyword is its row's
        ``param``: ``concurrency=``, ``dataroot=``, ``api_base=``, ``sample=``, ``batch_poll=``, ``name=``, …).

        What a manifest records is normalized here, as lightemma always has: ``dataroot`` made absolute,
        ``cache=True`` the default place (``cache.sqlite`` in the output directory) and a path made absolute, a
        prompt-set file's path made absolute, ``batch_poll`` kept only with ``batch``, numbers of the parser's
        limits and prices as floats. An unknown keyword is a TypeError, as in any Python call.
        """
        options = {row.key for row in BACKEND_OPTION_SETTINGS}
        unknown = sorted(k for k in keywords if k not in _BY_NAME and k != "name" or k in options)
        if unknown:
            raise TypeError(f"run() got an unexpected keyword argument {unknown[0]!r}")
        kw = dict(keywords)
        cache = kw.get("cache")
        kw["cache"] = DEFAULT_CACHE if cache is True else (os.fspath(Path(cache).resolve()) if cache else None)
        if kw.get("dataroot"):
            kw["dataroot"] = os.fspath(Path(kw["dataroot"]).resolve())
        prompt_set = kw.get("prompt_set")
        if isinstance(prompt_set, str) and prompt_set.endswith(".json"):  # a file: found by a resume from anywhere
            kw["prompt_set"] = os.fspath(Path(prompt_set).resolve())
        for name in ("speed_range", "price"):
            if isinstance(kw.get(name), (list, tuple)):
                kw[name] = tuple(float(x) if finite(x) else x for x in kw[name])
        if finite(kw.get("max_abs_curvature")):
            kw["max_abs_curvature"] = float(kw["max_abs_curvature"])
        if "scenes" in kw:
            kw["scenes"] = tuple(kw["scenes"]) if kw["scenes"] else None
        batch = bool(kw.get("batch", False))
        poll = kw.get("batch_poll", 30.0)
        kw["batch"], kw["batch_poll"] = batch, ((float(poll) if finite(poll) else poll) if batch else None)
        return cls._from_flat(model, kw)

    @classmethod
    def _from_flat(cls, model: Any, flat: Mapping[str, Any]) -> RunConfig:
        groups: dict[str, dict[str, Any]] = {"dataset": {}, "prompting": {}, "api": {}, "local": {}, "batch": {}}
        top: dict[str, Any] = {}
        for name, value in flat.items():
            row = _BY_NAME.get(name)
            if row is None:  # name
                top[name] = value
            elif row.group is None:
                top[row.key] = value
            else:
                groups[row.group][row.attr or row.key] = value
        return cls(
            model=model,
            **top,
            dataset=DatasetSettings(**groups["dataset"]),
            prompting=PromptingSettings(**groups["prompting"]),
            api=ApiSettings(**groups["api"]),
            local=LocalSettings(**groups["local"]),
            batch=BatchSettings(**groups["batch"]),
        )

    def replace(self, **keywords: Any) -> RunConfig:
        """A copy with the settings ``keywords`` names (by parameter: ``concurrency=``, ``timeout=``, ``rpm=``, …)
        changed, validated again (:class:`InvalidSetting`)."""
        top: dict[str, Any] = {}
        groups: dict[str, dict[str, Any]] = {}
        for name, value in keywords.items():
            row = _BY_NAME.get(name)
            if row is None and name != "name":
                raise TypeError(f"replace() got an unexpected keyword argument {name!r}")
            if row is None or row.group is None:
                top[name] = value
            else:
                groups.setdefault(row.group, {})[row.attr or row.key] = value
        changed = {g: replace(getattr(self, g), **values) for g, values in groups.items()}
        return replace(self, **top, **changed)

    # -- the manifest ----------------------------------------------------------------------------------------------

    def to_manifest(self) -> dict[str, Any]:
        """The manifest's ``config`` block (a new dict), key for key and value for value as runs record it."""
        out: dict[str, Any] = {}
        for row in SETTINGS:
            value = getattr(self if row.group is None else getattr(self, row.group), row.attr or row.key)
            if row.kind == "list" and value is not None:
                value = list(value)
            elif row.kind == "object":
                value = dict(value)
            if row.key == "batch_poll" and not self.batch.enabled:
                value = None
            if row.key == "samples" and value == 1:  # one chain per frame: the config block as it always was
                continue
            if row.key == "api_base":  # recorded without credentials (backends.retry.redact_url)
                value = redact_url(value)
            out[row.key] = value
        out["dataset"] = self.dataset.to_manifest()
        return out

    @classmethod
    def from_manifest(cls, config: Any, where: str | os.PathLike[str] = "") -> RunConfig:
        """The config a manifest's ``config`` block records; a one-line :class:`~lightemma.errors.UserError` naming
        the setting (``{where}: the manifest's config.timeout is -1, not a number greater than 0; start a new
        run``) for a block that is not one a run writes (a hand-edited file): a setting left out, of another kind,
        out of its range. A setting a run of an older lightemma did not record takes what it meant then
        (``absent`` of its row: no plausibility limits, the independent chain, …)."""
        if not isinstance(config, Mapping):
            raise UserError(f"{where}: the manifest has no run config; it was not written by `lightemma run`")

        def refuse(name: str, value: Any, kind: str) -> UserError:
            return UserError(
                f"{where}: the manifest's config.{name} is {short_repr(value)}, not {kind}; start a new run"
            )

        missing = [row.key for row in SETTINGS if row.required and row.key not in config]
        if missing:
            raise UserError(f"{where}: the manifest's config has no {', '.join(missing)}; start a new run")
        raw_dataset = config.get("dataset")
        dataset: dict[str, Any] = {}
        if raw_dataset is not None and not isinstance(raw_dataset, dict):
            raise refuse("dataset", raw_dataset, "an object")
        for row in DATASET_SETTINGS:
            if row.key in ("sample", "sample_seed"):
                continue
            value = (raw_dataset or {}).get(row.key, row.absent)
            what = problem(row, value)
            if what is not None:
                raise refuse(f"dataset.{row.key}", value, manifest_requirement(row, what))
            dataset[row.key] = value
        scenes = dataset.get("scenes")
        if scenes is not None and not all(isinstance(s, str) for s in scenes):
            raise refuse("dataset.scenes", scenes, "a list of scene names")
        sample = (raw_dataset or {}).get("sample")
        if sample is not None and not isinstance(sample, dict):
            raise refuse("dataset.sample", sample, "an object")
        if sample:
            n, seed = sample.get("n"), sample.get("seed")
            if type(n) is not int or n < 1 or (seed is not None and type(seed) is not int):
                raise refuse("dataset.sample", sample, '{"n": N, "seed": S} (whole numbers)')
            dataset.update(sample=n, sample_seed=seed)
        else:
            dataset.update(sample=None, sample_seed=0)
        options = config.get("backend_options")
        if isinstance(options, Mapping) and "api_key" in options:
            raise UserError(
                f"{where}: the manifest's backend_options carry an api_key; keys come from the environment "
                "only (--api-key-env NAME): start a new run"
            )
        flat: dict[str, Any] = {}
        for row in SETTINGS:
            value = config.get(row.key, row.absent)
            if value is None and row.absent is not None:  # an older run's null: what it meant then
                value = row.absent
            if row.key != "ray_address":  # the trust policy's (lightemma.pipeline.trust)
                what = problem(row, value)
                if what is not None:
                    raise refuse(row.key, value, manifest_requirement(row, what))
            flat[row.key] = value

        pairs = (
            ("speed_range", lambda v: len(v) == 2 and all(map(finite, v)) and v[0] < v[1], "[low, high]"),
            (
                "price",
                lambda v: len(v) == 2 and all(finite(x) and 0 <= x <= MAX_PRICE for x in v),
                f"[input, output] USD per million, each 0..{MAX_PRICE:g}",
            ),
        )
        for name, good, kind in pairs:
            if flat[name] is not None and not good(flat[name]):
                raise refuse(name, flat[name], kind)
        flat.update(dataset)
        model = flat.pop("model")
        try:
            return cls._from_flat(model, flat)
        except InvalidSetting as exc:  # a rule of the typed settings beyond the table's (a backend option's range, …)
            where_in = "backend_options." if exc.parameter in {r.key for r in BACKEND_OPTION_SETTINGS} else ""
            raise refuse(where_in + exc.parameter, exc.value, exc.requirement) from None
        except UserError as exc:
            raise UserError(f"{where}: the manifest's config: {exc}; start a new run") from None
