"""The API backend: any litellm model (OpenAI, Anthropic, Gemini, OpenAI-compatible servers).

Each request is one user turn: the frame's image as a base64 data URL plus the
stage text. Calls are asynchronous; concurrency is bounded by the runner, the
request/token rate by :class:`~lightemma.backends.ratelimit.RateLimiter`, and
transient failures (429, 5xx, timeouts, dropped connections) are retried here
with exponential backoff and jitter — litellm's own retries are switched off.
A call that still fails returns a :class:`ChatResult` with the error class and
a short, secret-free message; its text is never model text.
"""

from __future__ import annotations

import asyncio
import base64
import hashlib
import os
import time
from collections import OrderedDict
from collections.abc import Mapping, Sequence
from typing import Any

from lightemma._litellm import litellm
from lightemma.backends.base import ChatRequest, ChatResult, GenerationParams
from lightemma.backends.local import user_turn
from lightemma.backends.ratelimit import RateLimiter
from lightemma.backends.retry import FATAL, RetryPolicy, error_class, retry_after_seconds, short_message
from lightemma.cache import ResponseCache, request_key
from lightemma.errors import UserError
from lightemma.registry import ModelInfo, price_per_token, resolve

_MIME = {".jpg": "image/jpeg", ".jpeg": "image/jpeg", ".png": "image/png", ".webp": "image/webp"}
NO_KEY = "sk-no-key-required"
OPENAI_COMPATIBLE = ("openai", "hosted_vllm", "aiohttp_openai", "openai_like", "text-completion-openai")
# The providers of the paper's API models; an empty variable counts as missing.
PROVIDER_KEYS = {"openai": ("OPENAI_API_KEY",), "anthropic": ("ANTHROPIC_API_KEY",), "gemini": ("GEMINI_API_KEY", "GOOGLE_API_KEY")}
ESTIMATED_TOKENS_PER_CALL = 2000  # reserved from the TPM bucket until the provider reports usage


class FatalBackendError(UserError):
    """An error no retry can fix (bad key, unknown model, rejected parameter): the run stops."""


def litellm_model(info: ModelInfo, api_base: str | None) -> str:
    """The litellm model string for ``info``: local checkpoints behind ``--api-base`` go as ``openai/<id>``."""
    if api_base and info.backend in ("hf", "vllm"):
        return f"openai/{info.model_id}"
    return info.model_id


def require_api_key(model: str, api_base: str | None = None) -> str | None:
    """Check the provider's API key is set, before any work; return the key to pass explicitly, if any.

    For an OpenAI-compatible endpoint (``api_base``) a key is optional:
    ``OPENAI_API_KEY`` when set, else a placeholder. Otherwise a missing key is
    a :class:`UserError` naming the environment variable(s).
    """
    provider = _provider(model)
    if api_base and provider in OPENAI_COMPATIBLE:
        return os.environ.get("OPENAI_API_KEY") or NO_KEY
    if api_base:
        return None  # a custom base for another provider: litellm reads that provider's variables
    names = PROVIDER_KEYS.get(provider or "")
    if names is not None:
        missing = [] if any(os.environ.get(n, "").strip() for n in names) else list(names)
    else:
        check = litellm.validate_environment(model=model)
        missing = [] if check.get("keys_in_environment") else list(check.get("missing_keys") or [])
    if missing:
        names = " or ".join(missing)
        raise UserError(f"no API key for model {model!r}: set the environment variable {names} (or pass --api-base for an OpenAI-compatible server)")
    return None


def _provider(model: str) -> str | None:
    try:
        return litellm.get_llm_provider(model)[1]
    except Exception:  # noqa: BLE001 - an unknown provider is litellm's error to report at call time
        return None


def _secret_values() -> tuple[str, ...]:
    """Values of environment variables that look like credentials, to scrub from messages."""
    return tuple(v for k, v in os.environ.items() if len(v) >= 8 and any(t in k.upper() for t in ("KEY", "TOKEN", "SECRET")))


class _ImageCache:
    """Base64 data URLs (and content digests) of recently used images: each frame's image is read once.

    Bounded by total size (default 32 MiB of base64, about 150 CAM_FRONT images: enough for every frame
    in flight at concurrency ≤ 128), least recently used out first.
    """

    def __init__(self, max_bytes: int = 32 << 20) -> None:
        self.max_bytes = max_bytes
        self.bytes = 0
        self._items: OrderedDict[str, tuple[str, str]] = OrderedDict()

    def get(self, path: str) -> tuple[str, str]:
        item = self._items.get(path)
        if item is not None:
            self._items.move_to_end(path)
            return item
        with open(path, "rb") as fh:
            data = fh.read()
        mime = _MIME.get(os.path.splitext(path)[1].lower(), "image/jpeg")
        item = (f"data:{mime};base64,{base64.b64encode(data).decode('ascii')}", hashlib.sha256(data).hexdigest())
        self._items[path] = item
        self.bytes += len(item[0])
        while self.bytes > self.max_bytes and len(self._items) > 1:
            _, (url, _) = self._items.popitem(last=False)
            self.bytes -= len(url)
        return item


class APIBackend:
    """A litellm-backed model. See the module docstring for the call semantics."""

    name = "api"

    def __init__(
        self,
        model: str | ModelInfo,
        *,
        api_base: str | None = None,
        api_key: str | None = None,
        timeout: float = 120.0,
        retry: RetryPolicy | None = None,
        rpm: float | None = None,
        tpm: float | None = None,
        cache: ResponseCache | None = None,
        transport: str = "litellm",
    ) -> None:
        self.model_info = resolve(model) if isinstance(model, str) else model
        self.api_base = api_base
        self.model = litellm_model(self.model_info, api_base)
        self._api_key = api_key if api_key is not None else require_api_key(self.model, api_base)
        self.timeout = float(timeout)
        self.retry = retry or RetryPolicy()
        self.limiter = RateLimiter(rpm=rpm, tpm=tpm)
        self.cache = cache
        self._images = _ImageCache()
        self._secrets = tuple(s for s in (*_secret_values(), self._api_key or "") if s and s != NO_KEY)
        self._price = price_per_token(self.model_info)
        self._litellm_prices = True  # switched off after litellm fails to price this model once
        self._sends_temperature = self.model_info.supports_temperature and self._supports("temperature")
        self.transport = transport
        self._http = None
        if transport == "direct":
            if not api_base or _provider(self.model) not in OPENAI_COMPATIBLE:
                raise UserError(f"transport 'direct' needs --api-base and an OpenAI-compatible model string (openai/NAME), got {self.model!r}")
            from lightemma.backends.openai_http import OpenAIHTTPClient

            self._http = OpenAIHTTPClient(api_base, self._api_key, self.timeout)
            # the model name the server expects: the litellm provider prefix (openai/, hosted_vllm/, …) removed
            self._wire_model = self.model.split("/", 1)[1] if "/" in self.model else self.model
        elif transport != "litellm":
            raise UserError(f"unknown transport {transport!r}; choose litellm or direct")

    def _supports(self, param: str) -> bool:
        try:
            supported = litellm.get_supported_openai_params(model=self.model)
        except Exception:  # noqa: BLE001 - unknown model: assume the OpenAI parameter set
            return True
        return supported is None or param in supported

    def effective_params(self, params: GenerationParams) -> dict[str, Any]:
        """The decoding parameters actually sent (temperature omitted where the provider rejects it)."""
        out: dict[str, Any] = {"max_tokens": params.max_tokens}
        if self._sends_temperature:
            out["temperature"] = params.temperature
        return out

    @property
    def info(self) -> Mapping[str, Any]:
        return {
            "kind": "api",
            "transport": self.transport,
            "model": self.model,
            "api_base": self.api_base,
            "registry": self.model_info.to_dict(),
            "litellm_version": _litellm_version(),
            "token_counting": "provider-reported usage (prompt_tokens / completion_tokens)",
            "cost": ("litellm's bundled price list, else the registry's provider price" if self.transport == "litellm"
                     else "price list × provider-reported tokens (litellm's bundled list, else the registry's)"),
            "temperature_sent": self._sends_temperature,
            "timeout_s": self.timeout,
            "retry": {"max_retries": self.retry.max_retries, "base_s": self.retry.base, "cap_s": self.retry.cap},
            "rate_limit": {"rpm": self.limiter.requests.capacity if self.limiter.requests else None,
                           "tpm": self.limiter.tokens.capacity if self.limiter.tokens else None},
            "cache": str(self.cache.path) if self.cache else None,
            "gpus": 0,
        }

    async def generate(self, requests: Sequence[ChatRequest]) -> list[ChatResult]:
        """Answer every request concurrently, in order; failures come back as error results."""
        if len(requests) == 1:
            return [await self._call(requests[0])]
        return list(await asyncio.gather(*(self._call(r) for r in requests)))

    async def _call(self, req: ChatRequest) -> ChatResult:
        start = time.perf_counter()
        image_part: dict[str, Any] | None = None
        digest = None
        if req.image_path:
            try:
                url, digest = self._images.get(str(req.image_path))
            except OSError as exc:
                return ChatResult(text=None, error="ImageReadError", error_message=short_message(exc), seconds=time.perf_counter() - start)
            image_part = {"type": "image_url", "image_url": {"url": url}}
        messages = user_turn(req, image_part)
        params = self.effective_params(req.params)

        key = None
        if self.cache is not None and params.get("temperature", None) == 0:
            key = request_key(self.model, self.api_base, params, req.text, digest)
            hit = self.cache.get(key)
            if hit is not None:
                return ChatResult(text=hit["text"], input_tokens=hit["input_tokens"], output_tokens=hit["output_tokens"],
                                  seconds=time.perf_counter() - start, cost_cents=0.0, cached=True)

        retries = 0
        while True:
            await self.limiter.acquire(ESTIMATED_TOKENS_PER_CALL)
            try:
                result = await self._send(messages, params, start, retries)
            except asyncio.CancelledError:
                raise
            except Exception as exc:  # noqa: BLE001 - every provider error becomes a recorded error class
                err = error_class(exc)
                if err in FATAL:
                    raise FatalBackendError(f"{self.model}: {err}: {short_message(exc, secrets=self._secrets)}") from None
                if self.retry.should_retry(err, retries):
                    after = retry_after_seconds(exc)
                    if after:
                        self.limiter.pause(after)
                    await asyncio.sleep(self.retry.delay(retries, after))
                    retries += 1
                    continue
                return ChatResult(text=None, error=err, error_message=short_message(exc, secrets=self._secrets),
                                  seconds=time.perf_counter() - start, retries=retries)
            reported = [t for t in (result.input_tokens, result.output_tokens) if t is not None]
            # usage the provider did not report is unknown, not zero: the estimate then stays taken
            self.limiter.settle(ESTIMATED_TOKENS_PER_CALL, sum(reported) if reported else None)
            if key is not None and result.ok:
                self.cache.put(key, self.model, result.text, result.input_tokens, result.output_tokens, result.cost_cents)
            return result

    async def _send(self, messages: list[dict[str, Any]], params: dict[str, Any], start: float, retries: int) -> ChatResult:
        """One call over the configured transport; raises on a failed call."""
        if self._http is not None:
            data = await self._http.chat(self._wire_model, messages, params)
            usage = data.get("usage") or {}
            tin, tout = usage.get("prompt_tokens"), usage.get("completion_tokens")
            choice = (data.get("choices") or [{}])[0]
            text, finish = (choice.get("message") or {}).get("content"), choice.get("finish_reason")
            cost = self._price_cost(tin, tout)
        else:
            response = await litellm.acompletion(
                model=self.model, messages=messages, api_base=self.api_base, api_key=self._api_key,
                timeout=self.timeout, num_retries=0, max_retries=0, **params,
            )
            usage = getattr(response, "usage", None)
            tin, tout = getattr(usage, "prompt_tokens", None), getattr(usage, "completion_tokens", None)
            choices = getattr(response, "choices", None) or [None]
            text = getattr(getattr(choices[0], "message", None), "content", None)
            finish = getattr(choices[0], "finish_reason", None)
            cost = self._litellm_cost(response, tin, tout)
        seconds = time.perf_counter() - start
        if not text or not str(text).strip():
            return ChatResult(text=None, input_tokens=tin, output_tokens=tout, seconds=seconds, cost_cents=cost,
                              error="EmptyResponse", error_message=f"no answer text (finish_reason={finish})", retries=retries)
        return ChatResult(text=str(text), input_tokens=tin, output_tokens=tout, seconds=seconds, cost_cents=cost, retries=retries)

    def _litellm_cost(self, response: Any, tin: int | None, tout: int | None) -> float | None:
        """Cost in US cents: what litellm priced the call at (its bundled list), else the registry price."""
        usd = (getattr(response, "_hidden_params", None) or {}).get("response_cost")
        if usd is None and self._litellm_prices:
            try:
                usd = litellm.completion_cost(completion_response=response)
            except Exception:  # noqa: BLE001 - unknown model: fall back below, and stop asking
                self._litellm_prices = False
        if usd:
            return float(usd) * 100.0
        return self._price_cost(tin, tout)

    def _price_cost(self, tin: int | None, tout: int | None) -> float | None:
        """Cost in US cents from the per-token price (None when the price or the usage is unknown)."""
        if self._price is not None and tin is not None and tout is not None:
            return (tin * self._price[0] + tout * self._price[1]) * 100.0
        return None

    async def aclose(self) -> None:
        if self._http is not None:
            await self._http.aclose()
        if self.cache is not None:
            self.cache.close()


def _litellm_version() -> str | None:
    try:
        from importlib.metadata import version

        return version("litellm")
    except Exception:  # noqa: BLE001
        return None
