"""Which API errors to retry, and how long to wait: exponential backoff with full jitter.

Errors are classified by class name (litellm maps every provider's errors onto
the OpenAI exception classes), so this module needs no import of litellm.
"""

from __future__ import annotations

import random
import re
from dataclasses import dataclass

# Retried: rate limits, server errors, timeouts, dropped or truncated connections.
RETRYABLE = frozenset({
    "RateLimitError", "InternalServerError", "ServiceUnavailableError", "BadGatewayError", "Timeout",
    "APITimeoutError", "APIConnectionError", "APIError",
})
# Not retried here: an empty answer (e.g. every output token spent on reasoning) is the model's,
# and repeating the same request mostly repeats it; the chain's re-ask handles it as a failed attempt.
# Fatal for the whole run: retrying any frame cannot help (bad key, unknown model, bad parameters).
FATAL = frozenset({"AuthenticationError", "PermissionDeniedError", "NotFoundError", "UnsupportedParamsError", "PaymentRequiredError"})

_SECRETISH = re.compile(r"(sk-[A-Za-z0-9_\-]{6,}|AIza[0-9A-Za-z_\-]{10,}|(?i:bearer)\s+\S+|(?i:api[_-]?key)[=:]\s*\S+)")


def error_class(exc: BaseException) -> str:
    """The error class recorded for an exception (litellm / OpenAI class name)."""
    name = type(exc).__name__
    if name in ("TimeoutError", "ReadTimeout", "ConnectTimeout", "APITimeoutError"):
        return "Timeout"
    if name in ("InternalServerError", "APIError") and "Connection error" in str(exc):
        return "APIConnectionError"  # litellm files dropped/truncated connections under 500
    return name


def short_message(exc: BaseException, limit: int = 300, secrets: tuple[str, ...] = ()) -> str:
    """A short, single-line, secret-free description of ``exc``."""
    text = " ".join(str(exc).split())
    for secret in secrets:
        if secret:
            text = text.replace(secret, "***")
    text = _SECRETISH.sub("***", text)
    return text[:limit] + ("…" if len(text) > limit else "")


def retry_after_seconds(exc: BaseException) -> float | None:
    """The server's ``Retry-After`` (seconds) carried by a rate-limit or 5xx error, if any."""
    candidates = (getattr(exc, "litellm_response_headers", None), getattr(getattr(exc, "response", None), "headers", None),
                  getattr(exc, "headers", None))
    for headers in candidates:
        if not headers:
            continue
        value = headers.get("retry-after") or headers.get("Retry-After")
        if value is None:
            continue
        try:
            return max(0.0, float(value))
        except ValueError:
            return None
    return None


@dataclass(frozen=True)
class RetryPolicy:
    """Up to ``max_retries`` retries of a retryable error; waits base·2^k, capped, full jitter.

    A server's Retry-After is honoured (as the minimum wait, capped at ``cap``).
    """

    max_retries: int = 6
    base: float = 1.0
    cap: float = 60.0

    def should_retry(self, error: str, retries_done: int) -> bool:
        return error in RETRYABLE and retries_done < self.max_retries

    def delay(self, retries_done: int, retry_after: float | None = None, rng: random.Random | None = None) -> float:
        """Seconds to wait before retry number ``retries_done + 1``."""
        ceiling = min(self.cap, self.base * (2 ** retries_done))
        wait = (rng or random).uniform(0.0, ceiling)
        if retry_after is not None:
            wait = max(wait, min(retry_after, self.cap))
        return wait
