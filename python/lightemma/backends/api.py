"""The API backend: any litellm model (OpenAI, Anthropic, Gemini, OpenAI-compatible servers).

Each request is one user turn: the frame's image as a base64 data URL plus the
stage text. Calls are asynchronous; concurrency is bounded by the runner, the
request/token rate by :class:`~lightemma.backends.ratelimit.RateLimiter`, and
transient failures (429, 5xx, timeouts, dropped connections) are retried here
with exponential backoff and jitter — litellm's own retries are switched off.
A call that still fails returns a :class:`ChatResult` with the error class and
a short, secret-free message; its text is never model text.

Every call runs under lightemma's own deadline (``timeout``: connect to last
byte, whatever the transport does with its read timeouts). Before the first
call the model string is checked (litellm must know its provider). A failure no
retry can fix raises :class:`~lightemma.errors.RunFatalError` with the cause and
the fix: a rejected key or an unknown model at once, any other failure once
:class:`~lightemma.backends.retry.FailureStreak` sees it on frame after frame.
Usage a provider does not report stays unknown (None), never zero.

Requests are laid out for provider prefix caches: every request of a frame starts
with the same image (then the stage text, or the conversation's earlier turns),
so OpenAI's and Gemini's automatic caches hit from a frame's second request on;
for Anthropic, whose cache is explicit, the image part carries a cache breakpoint
(``cache_control``), and so does the last part of a conversation request that a
later stage extends. Cached input tokens are recorded per call as the provider
reports them (OpenAI ``prompt_tokens_details.cached_tokens``, Anthropic
``cache_read_input_tokens`` and ``cache_creation_input_tokens``, Gemini
``cachedContentTokenCount``), and costs price them as the provider bills them
(litellm's cost functions and bundled list; the registry's cache prices where
litellm lacks the model).
"""

from __future__ import annotations

import asyncio
import base64
import hashlib
import ipaddress
import os
import re
import time
from collections import OrderedDict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from lightemma._litellm import (
    lazy as litellm,
)  # imported at first use: the direct transport to an unlisted model never does
from lightemma.backends.base import Backend, ChatRequest, ChatResult, GenerationParams, is_truncated
from lightemma.backends.local import conversation
from lightemma.backends.ratelimit import RateLimiter
from lightemma.backends.retry import (
    FATAL,
    CallDeadline,
    FailureStreak,
    RetryPolicy,
    error_class,
    failure_signature,
    redact_url,
    retry_after_seconds,
    short_message,
    split_credentials,
    url_secrets,
)
from lightemma.cache import ResponseCache, request_key
from lightemma.errors import RunFatalError, UserError
from lightemma.inputs import read_image_bytes
from lightemma.models.catalog import ModelInfo, lookup, resolve, suggest
from lightemma.models.prices import _litellm_entry, cache_price_per_token, price_per_token, reasoning_budget, run_price

_MIME = {".jpg": "image/jpeg", ".jpeg": "image/jpeg", ".png": "image/png", ".webp": "image/webp"}
NO_KEY = "sk-no-key-required"
OPENAI_COMPATIBLE = ("openai", "hosted_vllm", "aiohttp_openai", "openai_like", "text-completion-openai")
# the providers litellm calls through the OpenAI SDK's client (the others post through its own HTTP handler)
OPENAI_SDK_PROVIDERS = ("openai", "text-completion-openai")
# The providers of the paper's API models; an empty variable counts as missing.
PROVIDER_KEYS = {
    "openai": ("OPENAI_API_KEY",),
    "anthropic": ("ANTHROPIC_API_KEY",),
    "gemini": ("GEMINI_API_KEY", "GOOGLE_API_KEY"),
}
# Each provider's own API hosts: its key goes there as the provider's variables hold it. Any other --api-base gets
# no provider key, only the key of a variable the user names for it (--api-key-env NAME).
PROVIDER_HOSTS = {
    "openai": ("api.openai.com",),
    "anthropic": ("api.anthropic.com",),
    "gemini": ("generativelanguage.googleapis.com",),
}
# Variables litellm, the OpenAI SDK and the batch adapters read for a provider's base URL when no --api-base is given.
BASE_VARIABLES = {
    "openai": ("OPENAI_BASE_URL", "OPENAI_API_BASE"),
    "anthropic": ("ANTHROPIC_API_BASE", "ANTHROPIC_BASE_URL"),
    "gemini": ("GEMINI_API_BASE",),
}
MAX_PRICE = 1e6  # USD per million tokens a --price may give (the dearest list price is ~1e2): beyond it, a typo or inf
ESTIMATED_TOKENS_PER_CALL = 2000  # reserved from the TPM bucket until the provider reports usage
# What a provider accepts per image, as base64 characters (what is sent), and the longest side in pixels.
# Anthropic: 5 MB per image, 8000 px; OpenAI: 20 MB per image; Gemini: 20 MB per request (kept under).
IMAGE_LIMITS: dict[str, tuple[int, int | None]] = {
    "anthropic": (5_000_000, 8000),
    "openai": (20_000_000, None),
    "gemini": (18_000_000, None),
    "vertex_ai": (18_000_000, None),
}
DEFAULT_IMAGE_LIMIT: tuple[int, int | None] = (20_000_000, None)
# Providers whose usage block leaves out a cache count that is zero (Gemini omits zero fields; Anthropic's are
# always there): a reported usage without one means no cached tokens, not unknown.
ZERO_WHEN_ABSENT = ("anthropic", "gemini", "vertex_ai")
CACHE_BREAKPOINT = {"type": "ephemeral"}  # Anthropic's cache_control (5-minute cache)

#: kept for callers that caught the API backend's own fatal error class
FatalBackendError = RunFatalError


def litellm_model(info: ModelInfo, api_base: str | None) -> str:
    """The litellm model string for ``info``: local checkpoints behind ``--api-base`` go as ``openai/<id>``, and so
    does a registry model of another provider (Anthropic, Gemini) served at an ``--api-base`` that is not that
    provider's own host: that server speaks the OpenAI-compatible protocol (``openai/claude-sonnet-4-6``)."""
    if api_base and info.backend in ("hf", "vllm"):
        return f"openai/{info.model_id}"
    if api_base and info.backend == "api" and lookup(info.key) is not None:
        native = _provider(info.model_id)
        if native is not None and native not in OPENAI_COMPATIBLE and not is_provider_host(native, api_base):
            return f"openai/{info.model_id.split('/', 1)[-1]}"
    return info.model_id


def require_api_key(model: str, api_base: str | None = None, api_key_env: str | None = None) -> str | None:
    """Check the key a call needs is set, before any work; return the key to pass explicitly, if any.

    A provider's own key (``OPENAI_API_KEY``, ``ANTHROPIC_API_KEY``, ``GEMINI_API_KEY``) goes only to that
    provider's own host (:data:`PROVIDER_HOSTS`). To any other ``api_base`` lightemma sends the key of the
    variable the user named for it (``api_key_env``, ``--api-key-env NAME``), else none at all (a
    placeholder: an OpenAI-compatible server without auth needs none). A missing or empty variable is a
    :class:`UserError` naming it.
    """
    if api_key_env:
        return key_from_variable(api_key_env)
    provider = _provider(model)
    if api_base and not is_provider_host(provider, api_base):
        return NO_KEY  # a server the user named without a key variable: no provider key goes there
    if api_base:  # the provider's own host (or a gateway declared as such): its key, read from its variables
        return (os.environ.get("OPENAI_API_KEY") or NO_KEY) if provider in OPENAI_COMPATIBLE else None
    names = PROVIDER_KEYS.get(provider or "")
    if names is not None:
        missing = [] if any(os.environ.get(n, "").strip() for n in names) else list(names)
    else:
        check = litellm.validate_environment(model=model)
        missing = [] if check.get("keys_in_environment") else list(check.get("missing_keys") or [])
    if missing:
        joined = " or ".join(missing)
        raise UserError(
            f"no API key for model {model!r}: set the environment variable {joined} (or pass --api-base for an OpenAI-compatible server)"
        )
    return None


def base_from_environment(provider: str | None, api_base: str | None) -> tuple[str, str] | None:
    """``(variable, url)`` of a base-URL variable (:data:`BASE_VARIABLES`) that would send ``provider``'s calls, and
    its key, elsewhere than ``--api-base``; None when ``api_base`` is given (it wins everywhere lightemma calls) or no
    such variable is set.

    A set variable must name the provider's own host or one ``LIGHTEMMA_PROVIDER_HOSTS`` declares to be its own
    (:func:`is_provider_host`): any other is a :class:`UserError` in one line, since the provider's key would go
    there and the calls would be billed at its list price (issue 25.5)."""
    if api_base:
        return None
    for name in BASE_VARIABLES.get(provider or "", ()):
        value = os.environ.get(name, "").strip()
        if not value:
            continue
        if not is_provider_host(provider, value):
            keys = " / ".join(PROVIDER_KEYS.get(provider or "", ())) or "the provider's key"
            raise UserError(
                f"the environment variable {name} is set to {redact_url(value)!r}: {provider} calls and "
                f"{keys} would go there, not to {provider}'s own API; unset it, or give that server as "
                f"--api-base (with --api-key-env NAME for its key), or declare it {provider}'s own host "
                f"with {PROVIDER_HOSTS_ENV}={provider}=HOST[:PORT]"
            )
        return name, value
    return None


def provider_key(provider: str | None) -> str | None:
    """The key ``provider``'s own variables hold (:data:`PROVIDER_KEYS`, first one set), or None.

    Only for that provider's own host: :func:`require_api_key` decides whether it goes anywhere at all."""
    return next((v for v in (os.environ.get(n, "").strip() for n in PROVIDER_KEYS.get(provider or "", ())) if v), None)


def key_from_variable(name: str) -> str:
    """The key held by the environment variable ``name`` (``--api-key-env``), or a :class:`UserError` naming it."""
    if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", name or ""):
        raise UserError(f"--api-key-env {name!r} is not an environment variable name")
    value = os.environ.get(name, "").strip()
    if not value:
        raise UserError(f"--api-key-env {name}: the environment variable {name} is not set (or is empty)")
    return value


CONNECT_TIMEOUT = 5.0  # seconds the --api-base reachability check waits for a TCP connection


def check_api_base(api_base: str) -> tuple[str, int]:
    """(host, port) of an ``--api-base`` URL, or a one-line :class:`UserError` for one without a scheme or host, or
    with a bad port (credentials in it are never shown)."""
    from urllib.parse import urlsplit

    shown = redact_url(api_base)
    try:
        parts = urlsplit(api_base)
        host, port = parts.hostname, parts.port
    except ValueError as exc:
        raise UserError(
            f"--api-base {shown!r} is not a usable URL ({exc}); give one like http://HOST:8000/v1"
        ) from None
    if parts.scheme.lower() not in ("http", "https") or not host:
        guess = f"http://{shown}" if "://" not in shown else shown
        raise UserError(f"--api-base {shown!r} needs a scheme and a host (http:// or https://), e.g. {guess}")
    return host, port or (443 if parts.scheme.lower() == "https" else 80)


def check_reachable(api_base: str, timeout: float = CONNECT_TIMEOUT) -> None:
    """Refuse, in one line, an ``--api-base`` whose host does not accept a TCP connection within ``timeout`` s."""
    import socket

    host, port = check_api_base(api_base)
    try:
        with socket.create_connection((host, port), timeout=timeout):
            pass
    except OSError as exc:
        why = "no answer within " + f"{timeout:g} s" if isinstance(exc, TimeoutError) else (exc.strerror or str(exc))
        raise UserError(
            f"--api-base {redact_url(api_base)}: cannot connect to {host}:{port} ({why}); check that the "
            "server runs and the URL (scheme, host, port)"
        ) from None


PROVIDER_HOSTS_ENV = "LIGHTEMMA_PROVIDER_HOSTS"


def _extra_provider_hosts(provider: str) -> list[str]:
    """Hosts the user declares to be ``provider``'s own (``LIGHTEMMA_PROVIDER_HOSTS=openai=gw.corp:8443,anthropic=…``):
    a gateway trusted with the provider's key and billing at its list price."""
    out = []
    for item in os.environ.get(PROVIDER_HOSTS_ENV, "").split(","):
        name, _, host = item.strip().partition("=")
        if name.strip().lower() == provider and host.strip():
            out.append(host.strip().lower())
    return out


def check_price(price: Any) -> None:
    """``--price``: two numbers from 0 to :data:`MAX_PRICE` (USD per million input / output tokens), else a one-line
    :class:`UserError`."""
    if len(price) != 2 or not all(
        isinstance(p, (int, float)) and not isinstance(p, bool) and 0 <= p <= MAX_PRICE for p in price
    ):
        raise UserError(
            f"--price needs two numbers from 0 to {MAX_PRICE:g} (USD per million input / output tokens), "
            f"got {' '.join(f'{p:g}' if isinstance(p, float) else str(p) for p in price)}"
        )


def is_provider_host(provider: str | None, api_base: str) -> bool:
    """True when ``api_base`` is ``provider``'s own API: https to one of :data:`PROVIDER_HOSTS`, or a host (or
    host:port) the environment's ``LIGHTEMMA_PROVIDER_HOSTS`` declares to be that provider's."""
    from urllib.parse import urlsplit

    try:
        parts = urlsplit(api_base)
        host = (parts.hostname or "").lower()
        port = parts.port
    except ValueError:
        return False
    if parts.scheme == "https" and host in PROVIDER_HOSTS.get(provider or "", ()):
        return True
    declared = _extra_provider_hosts(provider or "")
    return bool(declared) and (host in declared or (port is not None and f"{host}:{port}" in declared))


def is_loopback(host: str | None) -> bool:
    """True for ``localhost`` and loopback addresses (127.0.0.0/8, ::1)."""
    if not host:
        return False
    name = host.strip("[]").lower().rstrip(".")
    if name in ("localhost", "localhost.localdomain") or name.endswith(".localhost"):
        return True
    try:
        address = ipaddress.ip_address(name)
    except ValueError:
        import socket

        try:  # the shorthand forms an http client connects to as this machine: 127.1, 0x7f.1
            address = ipaddress.ip_address(socket.inet_aton(name))
        except OSError:
            return False
    mapped = getattr(address, "ipv4_mapped", None)  # ::ffff:127.0.0.1
    return address.is_loopback or address.is_unspecified or bool(mapped and mapped.is_loopback)


def _check_canonical_host(api_base: str) -> None:
    """Refuse, in one line, an IPv4 address in a shorthand form (``127.1``, ``2130706433``, ``127.000.000.001``): the
    direct transport's client (aiohttp) refuses it at every call, which would be retried as a connection error."""
    import socket
    from urllib.parse import urlsplit

    host = urlsplit(api_base).hostname or ""
    try:
        ipaddress.ip_address(host)
        return
    except ValueError:
        pass
    try:
        canonical = socket.inet_ntoa(socket.inet_aton(host))
    except OSError:
        return  # a name, resolved at the call
    raise UserError(
        f"--api-base {redact_url(api_base)}: write the address {host} as {canonical} for --transport direct "
        "(its client takes only the canonical form)"
    )


def insecure_endpoint(api_base: str | None, key_variable: str | None = None) -> str | None:
    """The warning for plain http to a host that is not this machine (None for https or loopback)."""
    if not api_base:
        return None
    from urllib.parse import urlsplit

    try:
        parts = urlsplit(api_base)
        host = parts.hostname
    except ValueError:
        return None
    if parts.scheme.lower() != "http" or is_loopback(host):
        return None
    what = f"the prompts, the images and the key in {key_variable}" if key_variable else "the prompts and the images"
    return f"warning: --api-base {redact_url(api_base)} is plain http to another host: {what} travel unencrypted; use https"


def check_model(model: str, name: str, api_base: str | None) -> str:
    """The provider litellm routes ``model`` to, or a :class:`UserError` naming the model, close names and the fix."""
    provider = _provider(model)
    if provider is not None:
        return provider
    close = suggest(name)
    hint = f"; did you mean {' or '.join(close)}?" if close else ""
    how = (
        f"for a model served at --api-base, name it openai/{name}"
        if api_base
        else "give a registry name (`lightemma models` lists them) or a litellm model string such as anthropic/claude-sonnet-4-6"
    )
    raise UserError(
        f"unknown model {name!r}: it is not in the registry and litellm cannot tell its provider{hint}; {how}"
    )


def _provider(model: str) -> str | None:
    prefix = model.split("/", 1)[0] if "/" in model else None
    if prefix in OPENAI_COMPATIBLE:
        return (
            prefix  # what litellm.get_llm_provider says of an explicit OpenAI-compatible prefix, without importing it
        )
    try:
        return litellm.get_llm_provider(model)[1]
    except Exception:  # noqa: BLE001 - an unknown provider is litellm's error to report at call time
        return None


def _secret_values() -> tuple[str, ...]:
    """Values of environment variables that look like credentials, to scrub from messages."""
    return tuple(
        v for k, v in os.environ.items() if len(v) >= 8 and any(t in k.upper() for t in ("KEY", "TOKEN", "SECRET"))
    )


def _b64_len(n: int) -> int:
    return 4 * ((n + 2) // 3)


def fit_image(data: bytes, max_b64: int, max_side: int | None) -> tuple[bytes, dict[str, Any]]:
    """``data`` re-encoded as JPEG to fit ``max_b64`` base64 characters and ``max_side`` pixels.

    Lowers the JPEG quality first (90 → 50), then the size (×0.75 per step, at quality 80). Returns the
    new bytes and what was done (original and new byte counts, quality, pixel size). Raises
    ``OSError`` when the image cannot be decoded or made to fit.
    """
    import io

    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(io.BytesIO(data)) as img:
            image = img.convert("RGB")
    except (UnidentifiedImageError, ValueError) as exc:
        raise OSError(f"cannot decode the image to shrink it: {exc}") from None
    original = image.size
    if max_side and max(image.size) > max_side:
        scale = max_side / max(image.size)
        image = image.resize(
            (max(1, int(image.width * scale)), max(1, int(image.height * scale))), Image.Resampling.LANCZOS
        )

    def encode(img: Any, quality: int) -> bytes:
        buffer = io.BytesIO()
        img.save(buffer, format="JPEG", quality=quality)
        return buffer.getvalue()

    def report(img: Any, out: bytes, quality: int) -> dict[str, Any]:
        return {
            "from_bytes": len(data),
            "to_bytes": len(out),
            "quality": quality,
            "size": list(img.size),
            "original_size": list(original),
        }

    for quality in (90, 80, 70, 60, 50):  # quality first: the picture keeps its resolution
        out = encode(image, quality)
        if _b64_len(len(out)) <= max_b64:
            return out, report(image, out, quality)
    while min(image.size) > 16:  # then size
        image = image.resize(
            (max(1, int(image.width * 0.75)), max(1, int(image.height * 0.75))), Image.Resampling.LANCZOS
        )
        out = encode(image, 80)
        if _b64_len(len(out)) <= max_b64:
            return out, report(image, out, 80)
    raise OSError(f"the image cannot be made to fit {max_b64} base64 characters")


class _ImageCache:
    """Base64 data URLs (and content digests) of recently used images: each frame's image is read once.

    Images over the provider's limit (``max_b64`` base64 characters, ``max_side`` pixels) are re-encoded to
    fit (:func:`fit_image`) and counted in ``reencoded`` (with the first few in ``examples``). Bounded by
    total size (default 32 MiB of base64, about 150 CAM_FRONT images: enough for every frame in flight at
    concurrency ≤ 128), least recently used out first.
    """

    def __init__(self, max_bytes: int = 32 << 20, *, max_b64: int | None = None, max_side: int | None = None) -> None:
        self.max_bytes = max_bytes
        self.max_b64 = max_b64
        self.max_side = max_side
        self.bytes = 0
        self.reencoded = 0
        self.examples: list[dict[str, Any]] = []
        self._seen_reencoded: set[str] = set()
        self._items: OrderedDict[str, tuple[str, str]] = OrderedDict()

    def _too_big(self, data: bytes) -> bool:
        if self.max_b64 is not None and _b64_len(len(data)) > self.max_b64:
            return True
        if self.max_side:
            import io

            from PIL import Image

            try:
                with Image.open(io.BytesIO(data)) as img:  # reads the header only
                    return max(img.size) > self.max_side
            except Exception:  # noqa: BLE001 - undecodable: the provider will say so
                return False
        return False

    def get(self, path: str) -> tuple[str, str]:
        item = self._items.get(path)
        if item is not None:
            self._items.move_to_end(path)
            return item
        data = read_image_bytes(path)  # a file, or a blank image (--inputs blank-image)
        mime = _MIME.get(os.path.splitext(path)[1].lower(), "image/jpeg")
        if path.startswith("corrupt:"):  # a corrupted image is a JPEG (lightemma.corruptions), whatever its source was
            mime = "image/jpeg"
        if self._too_big(data):
            data, done = fit_image(data, self.max_b64 or len(data) * 2, self.max_side)
            mime = "image/jpeg"
            if path not in self._seen_reencoded:  # counted once per image, however often it is re-read
                self._seen_reencoded.add(path)
                self.reencoded += 1
                if len(self.examples) < 3:
                    self.examples.append({"image": path, **done})
        item = (f"data:{mime};base64,{base64.b64encode(data).decode('ascii')}", hashlib.sha256(data).hexdigest())
        self._items[path] = item
        self.bytes += len(item[0])
        while self.bytes > self.max_bytes and len(self._items) > 1:
            _, (url, _) = self._items.popitem(last=False)
            self.bytes -= len(url)
        return item


class APIBackend(Backend):
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
        max_image_bytes: int | None = None,
        streak: FailureStreak | None = None,
        api_key_env: str | None = None,
        price: tuple[float, float] | None = None,
    ) -> None:
        self.model_info = resolve(model) if isinstance(model, str) else model
        if api_base:
            check_api_base(api_base)
        self.api_base = api_base
        self.api_base_shown = redact_url(api_base)  # what messages and records show: no credentials
        self.api_key_env = api_key_env
        self.model = litellm_model(self.model_info, api_base)
        self.provider = check_model(
            self.model, self.model_info.key, api_base
        )  # before the key: a typo is the first thing to say
        #: a declared gateway named by a base-URL variable of the environment (``OPENAI_BASE_URL`` …), or None
        self.base_variable = base_from_environment(self.provider, api_base)
        self._api_key = api_key if api_key is not None else require_api_key(self.model, api_base, api_key_env)
        #: one-line warnings for the caller to show once (plain http to another host)
        self.notices: list[str] = [
            n
            for n in (
                insecure_endpoint(
                    api_base, api_key_env or ("the key passed" if api_key is not None and api_key != NO_KEY else None)
                ),
            )
            if n
        ]
        if self.base_variable is not None:
            name, value = self.base_variable
            warning = insecure_endpoint(value, " / ".join(PROVIDER_KEYS.get(self.provider or "", ())) or None)
            if warning:
                self.notices.append(warning.replace("--api-base", name, 1))
        if not timeout or timeout <= 0:
            raise UserError(f"--timeout must be a positive number of seconds, got {timeout}")
        self.timeout = float(timeout)
        self.retry = retry or RetryPolicy()
        self.limiter = RateLimiter(rpm=rpm, tpm=tpm)
        self.cache = cache
        self.streak = streak or FailureStreak()
        self.reasoning_budget = reasoning_budget(self.model_info)
        limit_b64, max_side = IMAGE_LIMITS.get(self.provider, DEFAULT_IMAGE_LIMIT)
        if max_image_bytes is not None:
            if max_image_bytes < 1024:
                raise UserError(f"max_image_bytes must be at least 1024, got {max_image_bytes}")
            limit_b64 = int(max_image_bytes)
        self._images = _ImageCache(max_b64=limit_b64, max_side=max_side)
        self._secrets = tuple(
            s for s in (*url_secrets(api_base), *_secret_values(), self._api_key or "") if s and s != NO_KEY
        )
        # a model served from another --api-base is not the provider's: no list price (litellm's or the registry's)
        self.served_elsewhere = bool(api_base and not is_provider_host(self.provider, api_base))
        self.price_given = price
        if price is not None:
            check_price(price)
            self._price: tuple[float, float] | None = (price[0] / 1e6, price[1] / 1e6)
            # every input token at the given input price, cached and cache-write ones too (registry.run_price)
            self._cache_price: tuple[float | None, float | None] = (price[0] / 1e6, price[0] / 1e6)
        elif self.served_elsewhere:
            self._price, self._cache_price = None, (None, None)
        else:
            self._price = price_per_token(self.model_info)
            self._cache_price = cache_price_per_token(self.model_info)
        # switched off after litellm fails to price this model once, or when its list price does not apply
        self._litellm_prices = price is None and not self.served_elsewhere
        self._sends_temperature = self.model_info.supports_temperature and self._supports("temperature")
        self.transport = transport
        # user:password@ in --api-base: sent as Basic auth (the URL litellm gets carries none)
        self._litellm_base: str | None
        self._litellm_base, basic = split_credentials(api_base) if api_base else (api_base, None)
        self._litellm_extra: dict[str, Any] = {"extra_headers": {"Authorization": basic}} if basic else {}
        self._http = None
        self._client: Any = None  # litellm transport: the bounded OpenAI client, per event loop
        self._client_loop: Any = None
        if transport == "direct":
            if not api_base or _provider(self.model) not in OPENAI_COMPATIBLE:
                raise UserError(
                    f"transport 'direct' needs --api-base and an OpenAI-compatible model string (openai/NAME), got {self.model!r}"
                )
            from lightemma.backends.openai_http import OpenAIHTTPClient

            _check_canonical_host(api_base)
            self._http = OpenAIHTTPClient(api_base, self._api_key, self.timeout)
            # the model name the server expects: the litellm provider prefix (openai/, hosted_vllm/, …) removed
            self._wire_model = self.model.split("/", 1)[1] if "/" in self.model else self.model
        elif transport != "litellm":
            raise UserError(f"unknown transport {transport!r}; choose litellm or direct")

    @property
    def sent_key(self) -> str | None:
        """The key this backend sends, as :func:`require_api_key` decided it once: the key of ``--api-key-env``,
        the provider's own key when the destination is its own host, or None (no key at all: another
        ``--api-base`` without a key variable). Everything that calls the provider for this backend (the batch
        adapters included) sends this key and no other."""
        if self._api_key == NO_KEY:
            return None
        if self._api_key is not None:
            return self._api_key
        return provider_key(self.provider)

    def check_endpoint(self) -> None:
        """Before any work: the ``--api-base`` host accepts a connection (a one-line :class:`UserError` if not)."""
        if self.api_base:
            check_reachable(self.api_base)

    def _supports(self, param: str) -> bool:
        if self.api_base and self.provider in OPENAI_COMPATIBLE and not _litellm_lists(self.model):
            return True  # litellm gives an unlisted OpenAI-compatible model the whole OpenAI parameter set
        try:
            supported = litellm.get_supported_openai_params(model=self.model)
        except Exception:  # noqa: BLE001 - unknown model: assume the OpenAI parameter set
            return True
        return supported is None or param in supported

    def structured_output(self) -> dict[str, Any]:
        """How this model is constrained to a JSON schema (recorded in the manifest), or a :class:`UserError`.

        An OpenAI-compatible server at ``--api-base`` gets ``response_format`` as sent (vLLM and SGLang
        enforce it; a server that rejects it fails the first stage-3 calls, and the run stops with its
        message). Any other model needs litellm's own word (``litellm.supports_response_schema``, from its
        bundled list) that the provider constrains it: litellm would otherwise only paste the schema into
        the prompt, which makes no answer format-proof.
        """
        if self.api_base and self.provider in OPENAI_COMPATIBLE:
            return {
                "mechanism": "response_format json_schema (strict), enforced by the OpenAI-compatible server at "
                f"{self.api_base_shown}",
                "pair_count_enforced": True,
            }
        if not litellm.supports_response_schema(model=self.model):
            raise UserError(
                f"--answer-format structured: litellm {_litellm_version()} does not mark {self.model} as able to "
                "follow a JSON schema (it would only paste the schema into the prompt); use --answer-format text "
                "or a model that supports structured outputs"
            )
        if self.provider == "anthropic":
            native = _litellm_entry(self.model).get("supports_native_structured_output") is True
            mechanism = (
                "Anthropic structured outputs (output_format json_schema, mapped by litellm)"
                if native
                else "Anthropic forced tool call (litellm's json_tool_call; the schema guides but is not grammar-enforced)"
            )
            return {
                "mechanism": mechanism,
                "pair_count_enforced": False,
                "note": "Anthropic accepts no minItems/maxItems: litellm moves the pair count into the schema's description",
            }
        if self.provider in ("gemini", "vertex_ai"):
            return {
                "mechanism": "Gemini response schema (responseMimeType application/json, mapped by litellm)",
                "pair_count_enforced": True,
            }
        return {"mechanism": "response_format json_schema (strict)", "pair_count_enforced": True}

    def effective_params(self, params: GenerationParams) -> dict[str, Any]:
        """The decoding parameters actually sent (temperature omitted where the provider rejects it)."""
        out: dict[str, Any] = {"max_tokens": params.max_tokens + self.reasoning_budget}
        if self._sends_temperature:
            out["temperature"] = params.temperature
        return out

    @property
    def info(self) -> Mapping[str, Any]:
        return {
            "kind": "api",
            "transport": self.transport,
            "model": self.model,
            "api_base": self.api_base_shown,
            "api_base_from_environment": (
                f"{self.base_variable[0]}={redact_url(self.base_variable[1])}" if self.base_variable else None
            ),
            "api_key_env": self.api_key_env,
            "registry": self.model_info.to_dict(),
            "litellm_version": _litellm_version(),
            "token_counting": "provider-reported usage (prompt_tokens / completion_tokens)",
            "cached_input_tokens": "provider-reported: OpenAI prompt_tokens_details.cached_tokens, Anthropic "
            "cache_read_input_tokens (writes: cache_creation_input_tokens), Gemini cachedContentTokenCount",
            "prompt_cache": (
                "cache_control breakpoint after the image (and at the end of a conversation request a later "
                "stage extends)"
                if self.provider == "anthropic"
                else "automatic prefix cache of the provider: every request of a frame starts with the same image"
            ),
            "cost": (
                run_price(self.model_info, given=self.price_given)["source"]
                if self.price_given is not None
                else f"unknown: served from --api-base {self.api_base_shown}, not at the provider's list price (give --price)"
                if self.served_elsewhere
                else "litellm's cost of the call (bundled price list, cached and cache-write tokens at their prices), "
                "else the registry's provider prices"
                if self.transport == "litellm"
                else "litellm.cost_per_token on the provider-reported tokens (cached tokens at the cached price), "
                "else the registry's provider prices"
            ),
            "temperature_sent": self._sends_temperature,
            "reasoning": {
                "reasons": bool(self.reasoning_budget),
                "budget_tokens": self.reasoning_budget,
                "max_tokens_sent": "--max-tokens + budget_tokens (the answer keeps --max-tokens of room)",
            },
            "finish_reason": "as the provider reported it (litellm normalises length / MAX_TOKENS / max_tokens to 'length')",
            "image_limit": {
                "base64_chars": self._images.max_b64,
                "max_side_px": self._images.max_side,
                "over_it": "re-encoded as JPEG, quality 90 → 50, then ×0.75 in size, until it fits",
            },
            "timeout_s": self.timeout,
            "deadline": "lightemma's own, per call: connect to last byte",
            "retry": {
                "max_retries": self.retry.max_retries,
                "base_s": self.retry.base,
                "cap_s": self.retry.cap,
                "max_retry_after_s": self.retry.max_wait,
            },
            "rate_limit": {
                "rpm": self.limiter.requests.capacity if self.limiter.requests else None,
                "tpm": self.limiter.tokens.capacity if self.limiter.tokens else None,
            },
            "cache": str(self.cache.path) if self.cache is not None else None,
            "gpus": 0,
        }

    @property
    def image_report(self) -> dict[str, Any] | None:
        """Images re-encoded to fit the provider's limit so far (count and the first few), or None if none were."""
        if not self._images.reencoded:
            return None
        return {
            "count": self._images.reencoded,
            "limit_base64_chars": self._images.max_b64,
            "max_side_px": self._images.max_side,
            "examples": list(self._images.examples),
        }

    @property
    def cache_failure(self) -> str | None:
        """Why the response cache was switched off mid-session (:attr:`ResponseCache.failure`), or None."""
        return self.cache.failure if self.cache is not None else None

    async def generate(self, requests: Sequence[ChatRequest]) -> list[ChatResult]:
        """Answer every request concurrently, in order; failures come back as error results."""
        if len(requests) == 1:
            return [await self._call(requests[0])]
        return list(await asyncio.gather(*(self._call(r) for r in requests)))

    def sampling(self) -> str | None:
        """``"n"`` where the provider takes the OpenAI-style ``n`` parameter (litellm's parameter list for the model,
        or any OpenAI-compatible ``--api-base``), else ``"calls"``: K samples are K requests."""
        return "n" if self._supports("n") else "calls"

    async def generate_samples(self, request: ChatRequest, k: int) -> list[ChatResult]:
        """K samples of ``request``: with :meth:`sampling` ``"n"``, the samples not in the response cache in one
        request with ``n`` (the call's usage and cost on the first of them, 0 on the others), else K requests."""
        if k == 1 or self.sampling() != "n":
            return await super().generate_samples(request, k)
        from dataclasses import replace

        return await self._choices(replace(request, sample=0, samples=k), k)

    async def _call(self, req: ChatRequest) -> ChatResult:
        return (await self._choices(req, 1))[0]

    async def _choices(self, req: ChatRequest, n: int) -> list[ChatResult]:
        """``n`` = 1: the answer to ``req``; ``n`` > 1: samples 0..n-1 of ``req`` (cached ones replayed, the others
        asked for in one request with ``n``)."""
        start = time.perf_counter()
        image_part: dict[str, Any] | None = None
        digest = None
        if req.image_path:
            try:
                url, digest = self._images.get(str(req.image_path))
            except OSError as exc:
                failed = ChatResult(
                    text=None,
                    error="ImageReadError",
                    error_message=short_message(exc),
                    seconds=time.perf_counter() - start,
                )
                return [self._observe(req, failed)] * n
            image_part = {"type": "image_url", "image_url": {"url": url}}
        messages = conversation(req, image_part)
        if self.provider == "anthropic":
            _mark_cache_breakpoints(messages, image=image_part is not None, end=req.prefix_of_next)
        params = self.effective_params(req.params)
        if req.response_schema is not None:
            from lightemma.backends.structured import openai_response_format

            params["response_format"] = openai_response_format(req.response_schema)

        keys: list[str | None] = [None] * n
        found: dict[int, ChatResult] = {}
        if self.cache is not None and (params.get("temperature", None) == 0 or req.samples > 1):
            for i in range(n):  # a sampled run's draws are cached too, each by its sample index
                cache_key = request_key(
                    self.model,
                    self.api_base_shown,
                    params,
                    req.text,
                    digest,
                    req.turns,
                    req.attempt,
                    req.inputs,
                    sample=req.sample if n == 1 else i,
                )
                keys[i] = cache_key
                hit = self.cache.get(cache_key)
                if hit is not None:
                    found[i] = self._observe(
                        req,
                        ChatResult(
                            text=hit["text"],
                            input_tokens=hit["input_tokens"],
                            output_tokens=hit["output_tokens"],
                            seconds=time.perf_counter() - start,
                            cost_cents=0.0,
                            cached=True,
                        ),
                    )
        missing = [i for i in range(n) if i not in found]
        if not missing:
            return [found[i] for i in range(n)]
        if len(missing) > 1:
            params["n"] = len(missing)

        retries = 0
        while True:
            await self.limiter.acquire(ESTIMATED_TOKENS_PER_CALL)
            try:
                async with asyncio.timeout(self.timeout):  # the whole call, connect to last byte, on every transport
                    results = await self._send(messages, params, start, retries, len(missing))
            except asyncio.CancelledError:
                raise
            except Exception as exc:  # noqa: BLE001 - every provider error becomes a recorded error class
                if isinstance(exc, TimeoutError):
                    exc = CallDeadline(f"no complete answer within {self.timeout:g} s (connect to last byte)")
                err = error_class(exc)
                message = short_message(exc, secrets=self._secrets)
                if err in FATAL:
                    raise self._fatal(err, message) from None
                if self.retry.should_retry(err, retries):
                    after = retry_after_seconds(exc)
                    if self.retry.waits_too_long(after):
                        raise self._too_long_a_wait(err, message, after) from None
                    if after:
                        self.limiter.pause(after, limit=self.retry.max_wait)
                    await asyncio.sleep(self.retry.delay(retries, after))
                    retries += 1
                    continue
                failed = self._observe(
                    req,
                    ChatResult(
                        text=None,
                        error=err,
                        error_message=message,
                        seconds=time.perf_counter() - start,
                        retries=retries,
                    ),
                )
                return [found.get(i, failed) for i in range(n)]
            result = results[0]
            reported = [t for t in (result.input_tokens, result.output_tokens) if t is not None]
            # usage the provider did not report is unknown, not zero: the estimate then stays taken
            self.limiter.settle(ESTIMATED_TOKENS_PER_CALL, sum(reported) if reported else None)
            for i, one in zip(missing, results):
                key = keys[i]
                if (
                    key is not None
                    and self.cache is not None
                    and one.text is not None
                    and one.ok
                    and not is_truncated(one.finish_reason)
                ):
                    self.cache.put(key, self.model, one.text, one.input_tokens, one.output_tokens, one.cost_cents)
                found[i] = self._observe(req, one)
            return [found[i] for i in range(n)]

    def _observe(self, req: ChatRequest, result: ChatResult) -> ChatResult:
        """Feed the call's outcome to the failure streak; raise :class:`RunFatalError` when the run cannot succeed."""
        signature = None if result.ok else failure_signature(result.error or "Error", result.error_message)
        scene = getattr(req.frame, "scene_name", None) if req.frame is not None else None
        frames = self.streak.observe(
            req.stage, req.frame_id, signature, scene=scene if isinstance(scene, str) else None
        )
        if frames is not None:
            raise self._fatal(result.error or "Error", result.error_message or "", frames=frames, stage=req.stage)
        return result

    def _too_long_a_wait(self, err: str, message: str, after: float | None) -> RunFatalError:
        """The run-fatal error for a server that asks for a longer pause (Retry-After) than lightemma waits."""
        asked = "forever" if after == float("inf") else f"{after:g} s"
        what = (
            f"the provider asks to wait {asked} before the next request (Retry-After), longer than lightemma waits "
            f"for one ({self.retry.max_wait:g} s)"
        )
        if err == "RateLimitError":
            return RunFatalError(
                f"{self.model}: {err}: {message} — {what}: the account's rate limit or quota is exhausted; "
                "resume later, or set --rpm / --tpm to the account's limits",
                cause="quota-exhausted",
                error=err,
            )
        return RunFatalError(
            f"{self.model}: {err}: {message} — {what}: the provider is unavailable; resume later",
            cause="provider-error",
            error=err,
        )

    def _key_variables(self) -> str:
        if self.api_key_env:
            return f"{self.api_key_env} (sent to {self.api_base_shown})"
        if self.api_base and not is_provider_host(self.provider, self.api_base):
            names = PROVIDER_KEYS.get(self.provider or "", ("OPENAI_API_KEY",))
            return (
                f"a variable named with --api-key-env (e.g. --api-key-env {names[0]}): no provider key is sent to "
                f"--api-base {self.api_base_shown} unless its variable is named"
            )
        known = PROVIDER_KEYS.get(self.provider or "")
        return " or ".join(known) if known else "the provider's API key variable"

    def _fatal(self, err: str, message: str, *, frames: int | None = None, stage: str | None = None) -> RunFatalError:
        """The run-fatal error for ``err``: one line with what happened and what to do about it."""
        where = f"--api-base {self.api_base_shown}" if self.api_base else f"{self.provider or 'the provider'}"
        seen = f" on {frames} frames in a row ({stage} stage), nothing succeeding in between" if frames else ""
        what = f"{self.model}: {err}: {message}"
        if err == "AuthenticationError":
            return RunFatalError(
                f"{what} — the API key was rejected; set a valid key in {self._key_variables()}",
                cause="authentication",
                error=err,
            )
        if err == "PermissionDeniedError":
            return RunFatalError(
                f"{what} — the key may not use this model; check the key in {self._key_variables()} "
                "and the account's access",
                cause="authentication",
                error=err,
            )
        if err == "PaymentRequiredError":
            return RunFatalError(f"{what} — the provider account needs credit or billing", cause="billing", error=err)
        if err == "NotFoundError":
            fix = (
                "check --model (the name the server serves, as openai/NAME) and --api-base (it usually ends in /v1)"
                if self.api_base
                else "check --model; `lightemma models` lists the registry"
            )
            return RunFatalError(f"{what} — unknown model or endpoint; {fix}", cause="unknown-model", error=err)
        if err == "UnsupportedParamsError":
            return RunFatalError(
                f"{what} — the provider rejects a parameter lightemma sends "
                f"({', '.join(self.effective_params(GenerationParams()))})",
                cause="invalid-request",
                error=err,
            )
        if err == "EmptyResponse" and "finish_reason=length" in message:
            budget = f", of which {self.reasoning_budget} for reasoning" if self.reasoning_budget else ""
            return RunFatalError(
                f"{self.model}: the model spent its whole output budget without answering (finish_reason "
                f"length, no answer text){seen}; raise --max-tokens (each stage may now use --max-tokens"
                f"{' + ' + str(self.reasoning_budget) if self.reasoning_budget else ''} output tokens{budget})",
                cause="reasoning-budget",
                error=err,
            )
        if err == "EmptyResponse":
            return RunFatalError(
                f"{what}{seen} — the model answers with no text; check the model and its server",
                cause="empty-answers",
                error=err,
            )
        if err in ("APIConnectionError", "Timeout"):
            fix = f"check {where} and the network" + (
                f", or raise --timeout (now {self.timeout:g} s)" if err == "Timeout" else ""
            )
            return RunFatalError(
                f"{what}{seen} after {self.retry.max_retries} retries each — cannot reach the model; {fix}",
                cause="unreachable",
                error=err,
            )
        if err == "RateLimitError":
            return RunFatalError(
                f"{what}{seen} after {self.retry.max_retries} retries each — rate limited; lower --concurrency "
                "or set --rpm / --tpm to the account's limits",
                cause="rate-limit",
                error=err,
            )
        if err == "ImageReadError":
            return RunFatalError(
                f"{what}{seen} — the frames' images cannot be read; check the dataset's samples/ folder",
                cause="images",
                error=err,
            )
        if err == "ResponseEncodingError":
            return RunFatalError(
                f"{what}{seen} — every reply's body is in an encoding lightemma does not read, or does not "
                f"decode; check {where}",
                cause="invalid-response",
                error=err,
            )
        if err == "ResponseTooLargeError":
            from lightemma.backends.openai_http import MAX_BODY_BYTES

            return RunFatalError(
                f"{what}{seen} — every reply is larger than the {MAX_BODY_BYTES >> 20} MiB lightemma reads "
                f"(a chat completion is a few KiB); check {where} and the model it serves",
                cause="invalid-response",
                error=err,
            )
        if err in ("BadRequestError", "UnprocessableEntityError", "ContentPolicyViolationError"):
            return RunFatalError(
                f"{what}{seen} — every request is rejected the same way; fix what the message names "
                "(model, --max-tokens, images, the server)",
                cause="invalid-request",
                error=err,
            )
        return RunFatalError(
            f"{what}{seen} — the provider keeps failing; try again later", cause="provider-error", error=err
        )

    async def _send(
        self, messages: list[dict[str, Any]], params: dict[str, Any], start: float, retries: int, n: int = 1
    ) -> list[ChatResult]:
        """One call over the configured transport: its ``n`` answers (choices; a reply with fewer gives error
        results for the rest); the call's usage and cost on the first, 0 on the others. Raises on a failed call."""
        if self._http is not None:
            data = await self._http.chat(self._wire_model, messages, params)
            usage = _usage(data.get("usage"), self.provider)
            choices = [c if isinstance(c, dict) else {} for c in (data.get("choices") or [{}])]
            answers = [((c.get("message") or {}).get("content"), c.get("finish_reason")) for c in choices]
            cost = self._direct_cost(usage)
        else:
            from lightemma.backends.openai_http import body_guard

            with body_guard():  # what the body hooks refuse (too large, an encoding) is raised as itself
                response = await litellm.acompletion(
                    model=self.model,
                    messages=messages,
                    api_base=self._litellm_base,
                    api_key=self._api_key,
                    timeout=self.timeout,
                    num_retries=0,
                    max_retries=0,
                    **self._litellm_extra,
                    **self._bounded_client(),
                    **params,
                )
            usage = _usage(getattr(response, "usage", None), self.provider)
            answers = [
                (getattr(getattr(c, "message", None), "content", None), getattr(c, "finish_reason", None))
                for c in (getattr(response, "choices", None) or [None])
            ]
            cost = self._litellm_cost(response, usage)
        seconds = time.perf_counter() - start
        out = []
        for i in range(n):
            text, finish = answers[i] if i < len(answers) else (None, None)
            finish = str(finish) if finish is not None else None
            common: dict[str, Any] = dict(
                input_tokens=usage.input,
                output_tokens=usage.output,
                seconds=seconds,
                cost_cents=cost,
                retries=retries,
                finish_reason=finish,
                reasoning_tokens=usage.reasoning,
                cached_input_tokens=usage.cached,
                cache_write_tokens=usage.written,
            )
            if i > 0:  # the call is counted once, on its first answer: a share of it is not reported
                common.update(
                    input_tokens=0,
                    output_tokens=0,
                    cost_cents=0.0,
                    reasoning_tokens=0,
                    cached_input_tokens=0,
                    cache_write_tokens=0,
                )
            reasoning = usage.reasoning
            if i >= len(answers):
                out.append(
                    ChatResult(
                        text=None,
                        error="EmptyResponse",
                        error_message=f"the reply holds {len(answers)} answers, {n} were asked for (n)",
                        **common,
                    )
                )
            elif not text or not str(text).strip():
                spent = f", {reasoning} reasoning tokens" if reasoning else ""
                out.append(
                    ChatResult(
                        text=None,
                        error="EmptyResponse",
                        error_message=f"no answer text (finish_reason={finish}{spent})",
                        **common,
                    )
                )
            else:
                out.append(ChatResult(text=str(text), **common))
        return out

    def _bounded_client(self) -> dict[str, Any]:
        """``client=``: the client litellm calls through, reading at most
        :data:`~lightemma.backends.openai_http.MAX_BODY_BYTES` of a body (one per event loop): the OpenAI SDK's client
        for the OpenAI protocol, litellm's own HTTP handler for Anthropic's and Gemini's native protocols."""
        loop = asyncio.get_running_loop()
        if self._client_loop is not loop:
            from lightemma.backends.openai_http import limited_litellm_handler, limited_openai_client

            self._client = (
                limited_openai_client(self.sent_key or NO_KEY, self._litellm_base or None)
                if self.provider in OPENAI_SDK_PROVIDERS
                else limited_litellm_handler()
            )
            self._client_loop = loop
        return {"client": self._client}

    def _litellm_cost(self, response: Any, usage: Usage) -> float | None:
        """Cost in US cents: what litellm priced the call at (its bundled list, cached tokens at their price), else
        the registry price.

        None when the provider reported no usage: litellm would price that as zero tokens.
        """
        if usage.input is None or usage.output is None:
            return None
        if self.price_given is not None or self.served_elsewhere:
            return self._price_cost(usage)  # --price, or unknown: never the provider's list price
        usd = (getattr(response, "_hidden_params", None) or {}).get("response_cost")
        if usd is None and self._litellm_prices:
            try:
                usd = litellm.completion_cost(completion_response=response)
            except Exception:  # noqa: BLE001 - unknown model: fall back below, and stop asking
                self._litellm_prices = False
        if usd:
            return float(usd) * 100.0
        return self._price_cost(usage)

    def _direct_cost(self, usage: Usage) -> float | None:
        """Cost in US cents of a direct-transport call: ``litellm.cost_per_token`` on the reported tokens (cached
        tokens at the cached price) when litellm's list has the model, else the registry price."""
        if usage.input is None or usage.output is None:
            return None
        if self._litellm_prices and not _litellm_lists(self.model):
            self._litellm_prices = False  # litellm cannot price a model its list lacks (ModelNotMappedError)
        if self._litellm_prices:
            try:
                usd = sum(
                    litellm.cost_per_token(
                        model=self.model,
                        prompt_tokens=usage.input,
                        completion_tokens=usage.output,
                        cache_read_input_tokens=usage.cached or 0,
                        cache_creation_input_tokens=usage.written or 0,
                    )
                )
                return float(usd) * 100.0
            except Exception:  # noqa: BLE001 - not in litellm's list: the registry's price below, and stop asking
                self._litellm_prices = False
        return self._price_cost(usage)

    def _price_cost(self, usage: Usage) -> float | None:
        """Cost in US cents from the registry's per-token prices, cached and cache-write tokens at theirs.

        None when the price or the usage is unknown, or when cached tokens were reported whose price is unknown.
        """
        if self._price is None or usage.input is None or usage.output is None:
            return None
        (price_in, price_out), (price_read, price_write) = self._price, self._cache_price
        read, written = usage.cached or 0, usage.written or 0
        if (read and price_read is None) or (written and price_write is None):
            return None
        usd = (usage.input - read - written) * price_in + usage.output * price_out
        usd += read * (price_read or 0.0) + written * (price_write or 0.0)
        return usd * 100.0

    async def aclose(self) -> None:
        if self._http is not None:
            await self._http.aclose()
        if self._client is not None:
            client, self._client, loop, self._client_loop = self._client, None, self._client_loop, None
            if loop is asyncio.get_running_loop():
                await client.close()
        if self.cache is not None:
            self.cache.close()


@dataclass(frozen=True)
class Usage:
    """One call's tokens as the provider reported them; None = not reported (unknown, never zero).

    ``input`` counts every prompt token, ``cached`` those read from the provider's prompt cache and
    ``written`` those written to it (both included in ``input``); ``reasoning`` is of ``output``.
    """

    input: int | None = None
    output: int | None = None
    reasoning: int | None = None
    cached: int | None = None
    written: int | None = None


def _count(value: Any) -> int | None:
    return value if isinstance(value, int) and not isinstance(value, bool) and value >= 0 else None


def _usage(usage: Any, provider: str | None = None) -> Usage:
    """The tokens of an OpenAI-style usage block (a dict or litellm's object, which normalises Anthropic's and
    Gemini's: ``prompt_tokens`` includes cache reads and writes).

    A block that is missing, or says 0 input tokens (impossible for a non-empty prompt; litellm
    fills a missing block with zeros), is unknown. Cache counts a provider left out are zero for
    :data:`ZERO_WHEN_ABSENT` providers, unknown for the others (an OpenAI-compatible server may not say).
    """

    def get(obj: Any, name: str) -> Any:
        return obj.get(name) if isinstance(obj, Mapping) else getattr(obj, name, None)

    if usage is None:
        return Usage()
    tin, tout = get(usage, "prompt_tokens"), get(usage, "completion_tokens")
    if not isinstance(tin, int) or tin <= 0 or not isinstance(tout, int) or tout < 0:
        return Usage()
    details = get(usage, "completion_tokens_details")
    reasoning = _count(get(details, "reasoning_tokens")) if details is not None else None
    prompt_details = get(usage, "prompt_tokens_details")
    cached = _count(get(prompt_details, "cached_tokens")) if prompt_details is not None else None
    if cached is None:
        cached = _count(get(usage, "cache_read_input_tokens"))
    written = _count(get(usage, "cache_creation_input_tokens"))
    if provider in ZERO_WHEN_ABSENT:
        cached = 0 if cached is None else cached
        written = 0 if written is None else written
    return Usage(tin, tout, reasoning, cached, written)


def _mark_cache_breakpoints(messages: list[dict[str, Any]], *, image: bool, end: bool) -> None:
    """Anthropic cache breakpoints, in place (at most 3 of the 4 allowed).

    After the image (the first part of the first turn): every request of a frame reads it. In a
    conversation, also after the previous user turn (where the previous request ended and wrote its
    prefix: Anthropic looks for cached prefixes only at or before a breakpoint), and, when a later
    request extends this one (``end``), after its last part, so that the next request reads it all.
    """
    if image:
        messages[0]["content"][0]["cache_control"] = dict(CACHE_BREAKPOINT)
    if len(messages) >= 3:
        messages[-3]["content"][-1]["cache_control"] = dict(CACHE_BREAKPOINT)
    if end:
        messages[-1]["content"][-1]["cache_control"] = dict(CACHE_BREAKPOINT)


def _litellm_lists(model: str) -> bool:
    """Whether litellm's bundled list has ``model`` (as given or without its provider prefix), read without importing litellm."""
    from lightemma.models.prices import bundled_price_list

    listed = bundled_price_list()
    return model in listed or model.split("/", 1)[-1] in listed


def _litellm_version() -> str | None:
    try:
        from importlib.metadata import version

        return version("litellm")
    except Exception:  # noqa: BLE001
        return None
