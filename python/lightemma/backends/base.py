"""The one small interface every backend implements.

A backend turns chat requests (one prompt text plus, optionally, the frame's
CAM_FRONT image) into results. It is asynchronous and takes a *batch* of
requests, so that

* API backends run the requests of a batch concurrently, and
* local backends (``hf``, ``vllm``) can gather requests that arrive together
  into one batched forward pass.

The three-stage chain is written once, per frame, on top of this interface;
every backend (API, local, baselines) runs through the same chain, parser,
accounting and run store.

API errors are never model text: a failed call returns a :class:`ChatResult`
with ``text=None`` and ``error`` set to an error class name.

Every backend subclasses :class:`Backend`: three members to implement (``info``,
``generate``, ``aclose``) and optional capabilities with documented defaults
(``structured_output``, ``notices``, ``prepare``, ``attach``, the session reports,
…), which the runner calls on any backend. :mod:`lightemma.backends.factory` builds
every kind from one registry.
"""

from __future__ import annotations

import abc
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Self

from lightemma._text import unicode_clean
from lightemma.definitions import STAGES  # noqa: F401 - re-exported as lightemma.backends.STAGES
from lightemma.errors import UserError

#: finish reasons that mean "cut off at the output-token limit" (OpenAI / litellm, Anthropic, Gemini spellings)
TRUNCATED = frozenset({"length", "max_tokens", "max_output_tokens", "MAX_TOKENS"})


def is_truncated(finish_reason: str | None) -> bool:
    """True when a call's text was cut off at the output-token limit (``finish_reason`` length or the like)."""
    return finish_reason in TRUNCATED


@dataclass(frozen=True)
class GenerationParams:
    """Decoding parameters, recorded in every run's manifest."""

    temperature: float = 0.0
    max_tokens: int = 512


@dataclass(frozen=True)
class ResponseSchema:
    """A JSON schema the answer must match, enforced by the backend's constrained decoding.

    ``schema`` is the canonical JSON text of the schema (hashable, so that requests sharing one can
    share a batch); :meth:`as_dict` gives the object. ``name`` is what providers call it.
    """

    name: str
    schema: str

    @classmethod
    def of(cls, name: str, schema: Mapping[str, Any]) -> ResponseSchema:
        import json

        return cls(name=name, schema=json.dumps(schema, sort_keys=True, separators=(",", ":")))

    def as_dict(self) -> dict[str, Any]:
        import json

        schema: dict[str, Any] = json.loads(self.schema)
        return schema


@dataclass(frozen=True)
class ChatRequest:
    """One stage of one frame: the user turn ``text``, after the earlier ``turns`` of the conversation (if any).

    The image (if any) goes first in the first user turn: in ``turns[0]`` when there are earlier turns,
    else before ``text``. ``turns`` holds (user text, assistant text) exchanges, oldest first (the
    ``conversation`` chain); it is empty for the paper's independent stages. ``response_schema`` asks for
    an answer matching a JSON schema through the backend's structured-output mechanism.
    """

    text: str
    stage: str  # one of STAGES
    frame_id: str
    image_path: str | None = None
    params: GenerationParams = field(default_factory=GenerationParams)
    # The frame itself, for backends that need no model (baselines) — never sent to a provider.
    frame: Any = None
    turns: tuple[tuple[str, str], ...] = ()
    response_schema: ResponseSchema | None = None
    # A later request of the frame starts with this whole request (the conversation chain's stages 1 and 2):
    # a backend with an explicit prompt cache (Anthropic) marks its end for caching.
    prefix_of_next: bool = False
    # Which attempt of the frame's chain this request belongs to (1 = the first ask; re-asks count on, also
    # across --retry-failed passes): a re-ask is a new question to the provider, never a replay of a cached answer.
    attempt: int = 1
    # The run's input ablation (lightemma.inputs: full, no-image, blank-image, no-history); the chain has already
    # applied it to text and image — backends only key their response cache by it.
    inputs: str = "full"
    # Which of the frame's K independent chains (--samples K) this request belongs to (0..K-1) and K: a sample
    # other than 0 keys the response cache by its index; a sampled run (K > 1) caches its draws at any temperature.
    sample: int = 0
    samples: int = 1


@dataclass
class ChatResult:
    """What one call returned. ``text`` is None exactly when ``error`` is set."""

    text: str | None
    input_tokens: int | None = None
    output_tokens: int | None = None
    seconds: float = 0.0
    cost_cents: float | None = None
    error: str | None = None  # error class, e.g. "RateLimitError", "Timeout", "APIConnectionError"
    error_message: str | None = None  # short, secret-free description
    cached: bool = False  # answered from the response cache
    retries: int = 0  # transport-level retries before this result
    # Why generation stopped, as the provider said it ("stop", "length", "MAX_TOKENS", …); None when unknown.
    finish_reason: str | None = None
    # Of output_tokens, those spent on hidden reasoning (provider-reported); None when unknown.
    reasoning_tokens: int | None = None
    # Of input_tokens, those served from the provider's (or vLLM's) prefix cache; None when unknown.
    cached_input_tokens: int | None = None
    # Of input_tokens, those written to the provider's prompt cache (Anthropic bills them above the input price).
    cache_write_tokens: int | None = None

    def __post_init__(self) -> None:
        if self.text is not None:
            self.text = unicode_clean(self.text)
        if self.error_message is not None:
            self.error_message = unicode_clean(self.error_message)

    @property
    def ok(self) -> bool:
        return self.error is None and self.text is not None


class Backend(abc.ABC):
    """The base class of every backend: a model behind :meth:`generate`; :attr:`info` is recorded in the run manifest.

    A subclass implements :attr:`info`, :meth:`generate` and :meth:`aclose`. Every other member is an optional
    capability with the default documented at it, which a backend that has the capability overrides; the runner
    calls them unconditionally (it never asks whether a backend has a member). A backend is an async context
    manager: ``async with backend:`` closes it (:meth:`aclose`) on the way out; it needs no entering step, as
    it is ready when built (:meth:`prepare`, which needs the frame set, is the runner's own call).

    The class attributes below are data defaults: a subclass sets its own as class or instance attributes.
    """

    #: a short label for messages (``api``, ``hf``, ``baseline:cv``, …)
    name: str = "backend"
    #: the litellm provider that serves and bills the model (``openai``, ``anthropic``, …); None: no provider
    #: (a local model, a baseline). ``--estimate`` and ``--max-cost`` price calls by it.
    provider: str | None = None
    #: True when the model is served from an ``--api-base`` that is not its provider's own host: no list price
    #: applies (the run's price must be given)
    served_elsewhere: bool = False
    #: the endpoint as messages and records show it (credentials removed); None: no endpoint
    api_base_shown: str | None = None
    #: one-line warnings for the caller to show once, after the backend is built (plain http to another host, …);
    #: none by default
    notices: Sequence[str] = ()
    #: True when the runner must put every frame in flight at once, whatever the run's concurrency (a batch
    #: backend: each wave holds one stage of every pending frame); False by default
    wants_all_frames: bool = False

    # -- what every backend implements -----------------------------------------------------------------------

    @property
    @abc.abstractmethod
    def info(self) -> Mapping[str, Any]:
        """Backend kind, model id, GPUs used, how tokens are counted, … (JSON-able)."""

    @abc.abstractmethod
    async def generate(self, requests: Sequence[ChatRequest]) -> list[ChatResult]:
        """Answer every request, in order; never raises for a per-request failure (a failed call is a
        :class:`ChatResult` with ``error`` set); raises :class:`~lightemma.errors.RunFatalError` when the run
        cannot go on."""

    @abc.abstractmethod
    async def aclose(self) -> None:
        """Release connections, threads, GPU memory."""

    async def __aenter__(self) -> Self:
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self.aclose()

    # -- optional capabilities, with their defaults ----------------------------------------------------------

    def structured_output(self) -> dict[str, Any]:
        """How this backend constrains stage 3 to a JSON schema (``--answer-format structured``), recorded in the
        manifest; a :class:`~lightemma.errors.UserError` when it cannot.

        Default: it cannot (the UserError names the backend and the fix)."""
        raise UserError(
            f"--answer-format structured: the {self.name} backend cannot constrain answers to a JSON "
            "schema; use --answer-format text"
        )

    def sampling(self) -> str | None:
        """How this backend draws K independent samples of a request (``--samples K``): ``"n"`` (one request asks
        for K answers, the OpenAI-style ``n`` parameter), ``"calls"`` (K requests, each decoded with sampling) or
        None (it cannot sample: a run with K > 1 is refused before any call).

        Default: None."""
        return None

    async def generate_samples(self, request: ChatRequest, k: int) -> list[ChatResult]:
        """K samples of ``request`` (samples 0..k-1, in order), as :meth:`generate` answers them (a failed one is
        an error result). Default: k requests through :meth:`generate` (``sample`` = 0..k-1); a backend whose
        :meth:`sampling` is ``"n"`` overrides it with one request."""
        from dataclasses import replace

        return await self.generate([replace(request, sample=i, samples=k) for i in range(k)])

    def effective_params(self, params: GenerationParams) -> dict[str, Any] | None:
        """The decoding parameters actually sent for ``params`` (``params.sent`` of the manifest).

        Default: None (the backend does not report them; a local model or a baseline uses ``params`` as given)."""
        return None

    def check_endpoint(self) -> None:
        """Before any work: refuse an endpoint that accepts no connection (a one-line
        :class:`~lightemma.errors.UserError`). Default: nothing to check (no endpoint)."""
        return None

    def prepare(self, frames: Sequence[Any], dataset: Mapping[str, Any] | None = None) -> None:
        """Learn from the frame set before the run (``baseline:ego`` fits on it); ``dataset`` is the run's dataset
        request (dataroot, version, window, …). A fit shows in :attr:`info` as ``fit``. Default: nothing to learn."""
        return None

    def attach(self, run_dir: Any, log: Callable[[str], None] | None = None, budget: Any = None) -> None:
        """Bind the backend to a session's run directory (a batch backend journals its batches there), its logger
        and its ``--max-cost`` budget (:class:`~lightemma.pipeline.estimate.Budget` or None). Default: nothing."""
        return None

    @property
    def replica_report(self) -> dict[str, Any] | None:
        """Per-replica counters of this session (requests, deaths, restarts…), for the manifest's session.
        Default: None (one process, no replicas)."""
        return None

    @property
    def batch_report(self) -> dict[str, Any] | None:
        """What this session did through a provider's batch interface (waves, batches, turnarounds), for the
        manifest's session. Default: None (no batch interface)."""
        return None

    @property
    def image_report(self) -> dict[str, Any] | None:
        """Images re-encoded to fit the provider's limit in this session (count and the first few), or None.
        Default: None (images are sent as they are)."""
        return None

    @property
    def cache_failure(self) -> str | None:
        """Why the response cache was switched off mid-session (the session ran uncached from then on), or None.
        Default: None (no response cache)."""
        return None

    @property
    def stats(self) -> dict[str, Any] | None:
        """Micro-batching statistics (batches, requests, sizes) of a local model in this process, or None.
        Default: None (no micro-batching)."""
        return None
