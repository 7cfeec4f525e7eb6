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

A backend that can constrain answers to a JSON schema (``--answer-format
structured``) also has ``structured_output() -> dict``: how it does so (recorded
in the manifest), or a :class:`~lightemma.errors.UserError` saying why it cannot;
a backend without the method is refused for structured runs.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

from lightemma._text import unicode_clean

STAGES = ("scene", "intent", "actions")
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

        return json.loads(self.schema)


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


@runtime_checkable
class Backend(Protocol):
    """A model behind ``generate``. ``info`` is recorded in the run manifest."""

    name: str

    @property
    def info(self) -> Mapping[str, Any]:
        """Backend kind, model id, GPUs used, how tokens are counted, … (JSON-able)."""
        ...

    async def generate(self, requests: Sequence[ChatRequest]) -> list[ChatResult]:
        """Answer every request, in order; never raises for a per-request failure."""
        ...

    async def aclose(self) -> None:
        """Release connections, threads, GPU memory."""
        ...
