"""Which API errors to retry, how long to wait, and when a run cannot succeed.

Errors are classified by class name (litellm maps every provider's errors onto
the OpenAI exception classes), so this module needs no import of litellm. Three
kinds:

* **transient** (:data:`RETRYABLE`: 429, 5xx, timeouts, dropped connections) —
  retried here with exponential backoff and full jitter;
* **per-frame** (anything else, e.g. one image rejected, an empty answer) — the
  call fails, and the chain re-asks;
* **run-fatal** — :data:`FATAL` classes at once (a rejected key, an unknown
  model), or any failure that :class:`FailureStreak` sees repeat on frame after
  frame with nothing succeeding in between (the same 400 on every request, a dead
  endpoint, a reasoning budget that leaves no answer).
"""

from __future__ import annotations

import random
import re
from dataclasses import dataclass
from typing import overload

from lightemma.errors import InputError

# Retried: rate limits, server errors, timeouts, dropped or truncated connections.
RETRYABLE = frozenset(
    {
        "RateLimitError",
        "InternalServerError",
        "ServiceUnavailableError",
        "BadGatewayError",
        "Timeout",
        "APITimeoutError",
        "APIConnectionError",
        "APIError",
    }
)
# Not retried here: an empty answer (e.g. every output token spent on reasoning) is the model's,
# and repeating the same request mostly repeats it; the chain's re-ask handles it as a failed attempt.
# Fatal for the whole run: retrying any frame cannot help (bad key, unknown model, bad parameters).
FATAL = frozenset(
    {"AuthenticationError", "PermissionDeniedError", "NotFoundError", "UnsupportedParamsError", "PaymentRequiredError"}
)

_SECRETISH = re.compile(r"(sk-[A-Za-z0-9_\-]{6,}|AIza[0-9A-Za-z_\-]{10,}|(?i:bearer)\s+\S+|(?i:api[_-]?key)[=:]\s*\S+)")


# HTTP statuses whose meaning does not depend on the wording: litellm files some 401s under
# BadRequestError when the provider words them unusually ("You didn't provide an API key").
_BY_STATUS = {
    401: "AuthenticationError",
    402: "PaymentRequiredError",
    403: "PermissionDeniedError",
    404: "NotFoundError",
}


class CallDeadline(Exception):
    """A call that did not complete (connect to last byte) within lightemma's deadline; recorded as ``Timeout``."""


def error_class(exc: BaseException) -> str:
    """The error class recorded for an exception (litellm / OpenAI class name; by HTTP status where it is decisive)."""
    name = type(exc).__name__
    status = getattr(exc, "status_code", None) or getattr(exc, "status", None)
    if isinstance(status, int) and status in _BY_STATUS:
        return _BY_STATUS[status]
    if name in ("TimeoutError", "ReadTimeout", "ConnectTimeout", "APITimeoutError", "CallDeadline"):
        return "Timeout"
    if name in ("InternalServerError", "APIError") and "Connection error" in str(exc):
        return "APIConnectionError"  # litellm files dropped/truncated connections under 500
    return name


def short_message(exc: BaseException | str, limit: int = 300, secrets: tuple[str, ...] = ()) -> str:
    """A short, single-line, secret-free description of ``exc`` (an exception or its text)."""
    text = " ".join(str(exc).split())
    for secret in secrets:
        if secret:
            text = text.replace(secret, "***")
    text = _SECRETISH.sub("***", text)
    return text[:limit] + ("…" if len(text) > limit else "")


_SECRET_QUERY = re.compile(r"(?i)(key|token|secret|passw|auth|sig|credential)")


@overload
def redact_url(url: str) -> str: ...
@overload
def redact_url(url: None) -> None: ...
def redact_url(url: str | None) -> str | None:
    """``url`` as it may be shown or recorded: credentials in it (``user:pw@``) and secret-named query
    values (``?api_key=…``, ``token``, ``sig``, …) replaced by ``***``; anything else as given."""
    if not url:
        return url
    from urllib.parse import parse_qsl, urlencode, urlsplit, urlunsplit

    try:
        parts = urlsplit(url)
    except ValueError:
        return _SECRETISH.sub("***", url.split("@")[-1])
    netloc = parts.netloc
    if "@" in netloc:
        netloc = "***@" + netloc.rsplit("@", 1)[1]
    elif not netloc and "@" in url.split("?", 1)[0].split("#", 1)[0]:
        # no authority parsed (no scheme, "http:/…", "http//…"): whatever precedes an "@" may be credentials
        head = re.split(r"[?#]", url, maxsplit=1)[0]
        return _SECRETISH.sub("***", "***@" + head.rsplit("@", 1)[1] + url[len(head) :])
    query = parts.query
    if query:
        pairs = parse_qsl(query, keep_blank_values=True)
        query = urlencode([(k, "***" if _SECRET_QUERY.search(k) else v) for k, v in pairs], safe="*")
    return urlunsplit((parts.scheme, netloc, parts.path, query, parts.fragment))


def split_credentials(url: str) -> tuple[str, str | None]:
    """``url`` without its user info, and that user info as an HTTP ``Authorization: Basic`` value (None if none)."""
    import base64
    from urllib.parse import unquote, urlsplit, urlunsplit

    try:
        parts = urlsplit(url)
    except ValueError:
        return url, None
    if "@" not in parts.netloc:
        return url, None
    userinfo, host = parts.netloc.rsplit("@", 1)
    user, _, password = userinfo.partition(":")
    token = base64.b64encode(f"{unquote(user)}:{unquote(password)}".encode()).decode("ascii")
    return urlunsplit((parts.scheme, host, parts.path, parts.query, parts.fragment)), f"Basic {token}"


def url_secrets(url: str | None) -> tuple[str, ...]:
    """The credentials a URL carries (its user info, password and secret-named query values), to scrub from messages."""
    if not url:
        return ()
    from urllib.parse import parse_qsl, unquote, urlsplit

    try:
        parts = urlsplit(url)
    except ValueError:
        return ()
    out: list[str] = []
    if "@" in parts.netloc:
        userinfo = parts.netloc.rsplit("@", 1)[0]
        out += [userinfo, unquote(userinfo), *[unquote(x) for x in userinfo.split(":", 1)]]
        basic = split_credentials(url)[1]  # the header it is sent as: a server may echo it back
        if basic:
            out += [basic, basic.split(" ", 1)[1]]
    out += [v for k, v in parse_qsl(parts.query, keep_blank_values=True) if _SECRET_QUERY.search(k) and v]
    return tuple(sorted({s for s in out if len(s) >= 3}, key=len, reverse=True))


def retry_after_seconds(exc: BaseException) -> float | None:
    """The server's ``Retry-After`` (seconds) carried by a rate-limit or 5xx error, if any.

    Seconds (``"3"``, ``"0.5"``) or an HTTP date (seconds from now). ``inf`` stays ``inf`` (a wait no
    run can make: the caller refuses it); a value that is neither, or NaN, is None (no server wait).
    """
    candidates = (
        getattr(exc, "litellm_response_headers", None),
        getattr(getattr(exc, "response", None), "headers", None),
        getattr(exc, "headers", None),
    )
    for headers in candidates:
        if not headers:
            continue
        try:
            value = headers.get("retry-after") or headers.get("Retry-After")
        except Exception:  # noqa: BLE001 - a headers object we cannot read carries no wait
            return None
        if value is None:
            continue
        return _parse_retry_after(str(value))
    return None


def _parse_retry_after(value: str) -> float | None:
    try:
        seconds = float(value)
    except ValueError:
        from email.utils import parsedate_to_datetime

        try:
            when = parsedate_to_datetime(value)
        except (TypeError, ValueError, IndexError):
            return None
        if when is None:
            return None
        import datetime as _dt

        if when.tzinfo is None:
            when = when.replace(tzinfo=_dt.UTC)
        seconds = (when - _dt.datetime.now(_dt.UTC)).total_seconds()
    if seconds != seconds:  # NaN
        return None
    return max(0.0, seconds)


@dataclass(frozen=True)
class RetryPolicy:
    """Up to ``max_retries`` retries of a retryable error; waits base·2^k, capped, full jitter.

    A server's Retry-After is honoured as the minimum wait up to ``max_wait`` (60 s): the longest
    lightemma waits for any one server-asked pause. A Retry-After beyond it (an hour, ``inf``)
    is not waited out at all — :meth:`waits_too_long` — the run stops as rate-limited / quota exhausted
    (resumable) instead of freezing.
    """

    max_retries: int = 6
    base: float = 1.0
    cap: float = 60.0
    max_wait: float = 60.0  # the longest server-asked pause (Retry-After) that is waited out

    def should_retry(self, error: str, retries_done: int) -> bool:
        return error in RETRYABLE and retries_done < self.max_retries

    def waits_too_long(self, retry_after: float | None) -> bool:
        """True when a server asks for a longer pause than lightemma ever waits (``max_wait``)."""
        return retry_after is not None and retry_after > self.max_wait

    def delay(self, retries_done: int, retry_after: float | None = None, rng: random.Random | None = None) -> float:
        """Seconds to wait before retry number ``retries_done + 1``."""
        ceiling = min(self.cap, self.base * (2**retries_done))
        wait = (rng or random).uniform(0.0, ceiling)
        if retry_after is not None:
            wait = max(wait, min(retry_after, self.cap))  # the limiter pause holds the rest, up to max_wait
        return wait


# Failures whose wording tells one cause from another (one image rejected vs. every request rejected).
_WORDED = frozenset({"BadRequestError", "UnprocessableEntityError", "EmptyResponse", "ContentPolicyViolationError"})
# Of those, the rejections that may be about one request's content (its image), not the run's settings.
_CONTENT_TIED = _WORDED - {"EmptyResponse"}


def failure_signature(error: str, message: str | None) -> tuple[str, str]:
    """What makes two failures "the same": the error class, plus the message with digits masked for request errors."""
    if error not in _WORDED or not message:
        return (error, "")
    text = re.sub(r"\d+", "#", " ".join(message.lower().split()))
    return (error, text[:160])


class FailureStreak:
    """Notices a run that cannot succeed: the same failure on frame after frame, and nothing working.

    Per stage, failures are grouped by :func:`failure_signature`; a success of that stage
    clears its groups. A group that spans ``cold`` distinct frames while no call of any stage
    has succeeded yet in this session (a typo'd model, a dead endpoint, a request every
    provider call rejects), or ``warm`` distinct frames once something has worked (a key that
    ran out, a server that went down), makes :meth:`observe` return the number of frames.
    Re-asks of one frame count once, so a frame whose own image is rejected never stops a run.

    A request error whose wording may be about the request's own content (:data:`_CONTENT_TIED`: a
    rejected image, a content policy) can be tied to particular frames rather than to the run — a provider that
    rejects the images of one scene only. Such a group is fatal only once its frames span two scenes
    (when the callers say which scene a frame is of): otherwise the run goes on past those frames
    (they end ``failed`` with the provider's message), and a resume does too.
    """

    def __init__(self, cold: int = 3, warm: int = 5) -> None:
        if not 1 <= cold <= warm:
            raise InputError(f"need 1 <= cold <= warm, got cold={cold}, warm={warm}")
        self.cold = cold
        self.warm = warm
        self.succeeded = False
        self._groups: dict[str, dict[tuple[str, str], dict[str, str | None]]] = {}

    def observe(
        self, stage: str, frame_id: str, signature: tuple[str, str] | None, scene: str | None = None
    ) -> int | None:
        """Record one call's outcome (``signature`` None = success); the streak's frame count when it is fatal.

        ``scene``: the frame's scene, where known (see the class docstring).
        """
        if signature is None:
            self.succeeded = True
            self._groups.pop(stage, None)
            return None
        frames = self._groups.setdefault(stage, {}).setdefault(signature, {})
        frames[frame_id] = scene
        need = self.warm if self.succeeded else self.cold
        if len(frames) < need:
            return None
        scenes = set(frames.values())
        if signature[0] in _CONTENT_TIED and None not in scenes and len(scenes) < 2:
            return None  # maybe tied to this scene's frames, not to the run
        return len(frames)
