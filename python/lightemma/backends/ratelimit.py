"""A client-side rate limiter: requests and tokens per minute, queueing rather than rejecting.

litellm's router rejects over-limit calls; a benchmark wants them to wait. Two
token buckets (requests, tokens) refill continuously; ``acquire`` waits until
both have room. A server-sent ``Retry-After`` pauses every caller (``pause``),
so one 429 does not trigger a stampede of doomed retries.
"""

from __future__ import annotations

import asyncio
import time

from lightemma.errors import InputError

MAX_PAUSE = (
    60.0  # seconds: the longest a server-asked pause (Retry-After) holds the callers (RetryPolicy.cap's default)
)


class _Bucket:
    """A continuously refilling bucket of ``per_minute`` units (capacity one minute's worth)."""

    def __init__(self, per_minute: float) -> None:
        if per_minute <= 0:
            raise InputError(f"rate limit must be positive, got {per_minute}")
        self.capacity = float(per_minute)
        self.rate = per_minute / 60.0
        self.level = self.capacity
        self.stamp = time.monotonic()

    def _refill(self, now: float) -> None:
        self.level = min(self.capacity, self.level + (now - self.stamp) * self.rate)
        self.stamp = now

    def wait_time(self, amount: float, now: float) -> float:
        """Seconds until ``amount`` units are available (0 if now)."""
        self._refill(now)
        amount = min(amount, self.capacity)  # a request larger than a minute's budget waits for a full bucket
        return 0.0 if self.level >= amount else (amount - self.level) / self.rate

    def take(self, amount: float) -> None:
        self.level -= min(amount, self.capacity)

    def give(self, amount: float) -> None:
        self.level = min(self.capacity, self.level + amount)


class RateLimiter:
    """Requests-per-minute and tokens-per-minute limits for one model endpoint.

    ``acquire(tokens)`` reserves one request and an estimate of its tokens;
    ``settle(estimate, actual)`` corrects the token bucket once the provider
    reports usage. Either limit may be None (unlimited).
    """

    def __init__(self, rpm: float | None = None, tpm: float | None = None) -> None:
        self.requests = _Bucket(rpm) if rpm else None
        self.tokens = _Bucket(tpm) if tpm else None
        self._paused_until = 0.0
        self.waited = 0.0  # total seconds callers spent waiting here

    @property
    def active(self) -> bool:
        return self.requests is not None or self.tokens is not None

    def pause(self, seconds: float, *, limit: float = MAX_PAUSE) -> None:
        """Hold every caller for ``seconds`` from now (a server asked us to back off), at most ``limit`` seconds.

        The caller refuses longer waits (:meth:`RetryPolicy.waits_too_long`); the cap here makes sure no
        value (``inf``, an hour) can freeze every caller however it arrives.
        """
        if not seconds == seconds:  # NaN
            return
        seconds = min(max(0.0, seconds), limit)
        self._paused_until = max(self._paused_until, time.monotonic() + seconds)

    async def acquire(self, tokens: float = 0.0) -> None:
        """Wait until one request and ``tokens`` tokens fit in the limits, then take them.

        The check and the take happen with no ``await`` between them, so the
        event loop makes them atomic without a lock.
        """
        start = time.monotonic()
        while True:
            now = time.monotonic()
            wait = max(0.0, self._paused_until - now)
            if self.requests is not None:
                wait = max(wait, self.requests.wait_time(1, now))
            if self.tokens is not None and tokens:
                wait = max(wait, self.tokens.wait_time(tokens, now))
            if wait <= 0:
                break
            await asyncio.sleep(wait)
        if self.requests is not None:
            self.requests.take(1)
        if self.tokens is not None and tokens:
            self.tokens.take(tokens)
        self.waited += time.monotonic() - start

    def settle(self, estimate: float, actual: float | None) -> None:
        """Correct the token bucket by the difference between the estimate and the actual usage."""
        if self.tokens is None or actual is None:
            return
        diff = estimate - actual
        if diff > 0:
            self.tokens.give(diff)
        else:
            self.tokens.take(-diff)
