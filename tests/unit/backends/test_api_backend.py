"""The litellm API backend against a real loopback server: retries, errors, cache, limits."""

import asyncio
import base64
import time

import pytest
from PIL import Image

from lightemma.backends import ChatRequest, GenerationParams, create_backend
from lightemma.backends.api import FatalBackendError
from lightemma.backends.ratelimit import RateLimiter
from lightemma.backends.retry import RETRYABLE, RetryPolicy, short_message
from lightemma.cache import ResponseCache
from lightemma.errors import UserError
from lightemma.models.catalog import DEFAULT_REASONING_BUDGET
from tests.support.fake_openai import FakeOpenAIServer, Reply

FAST = RetryPolicy(max_retries=3, base=0.01, cap=0.05)
TRANSPORTS = pytest.mark.parametrize("transport", ["litellm", "direct"])


@pytest.fixture
def image(tmp_path):
    path = tmp_path / "cam.jpg"
    Image.new("RGB", (8, 8), (10, 20, 30)).save(path)
    return path


def ask(backend, text="describe", image=None, params=GenerationParams()):
    req = ChatRequest(
        text=text, stage="scene", frame_id="scene-1/a", image_path=str(image) if image else None, params=params
    )
    return asyncio.run(backend.generate([req]))[0]


@TRANSPORTS
def test_a_call_sends_one_image_as_data_url_with_temperature_0_and_512_tokens(image, transport):
    with FakeOpenAIServer() as server:
        backend = create_backend("openai/gpt-4o", api_base=server.url, retry=FAST, transport=transport)
        result = ask(backend, image=image)
    assert result.ok and result.text.startswith("A two-lane urban road")
    assert (result.input_tokens, result.output_tokens, result.retries, result.cached) == (1000, 50, 0, False)
    assert result.cost_cents == pytest.approx((1000 * 2.5e-6 + 50 * 1e-5) * 100)  # litellm's gpt-4o price
    body = server.requests[0].body
    assert body["model"] == "gpt-4o" and body["temperature"] == 0 and body["max_tokens"] == 512
    images = [p for p in body["messages"][0]["content"] if p["type"] == "image_url"]
    assert len(images) == 1
    assert images[0]["image_url"]["url"] == "data:image/jpeg;base64," + base64.b64encode(image.read_bytes()).decode()


def test_models_that_reject_temperature_0_get_none_sent(image):
    with FakeOpenAIServer() as server:
        backend = create_backend("gpt-5", api_base=server.url, retry=FAST)
        assert ask(backend).ok
    assert "temperature" not in server.requests[0].body
    assert backend.info["temperature_sent"] is False


# The client's timeout is short only where the case is a timeout: elsewhere a loaded machine (litellm's first
# call sets itself up inside the attempt's deadline) could time an attempt out before it reaches the server.
@pytest.mark.parametrize(
    ("first", "timeout"),
    [
        (Reply.error(429, retry_after=0.3), 30),
        (Reply.error(500), 30),
        (Reply.error(503), 30),
        (Reply(content="x" * 400, truncate=True), 30),
        (Reply(content="late", delay=6), 2),
        (Reply(reset=True), 30),
    ],
    ids=["429-retry-after", "500", "503", "truncated-body", "timeout", "connection-reset"],
)
@TRANSPORTS
def test_transient_failures_are_retried_then_succeed(first, timeout, transport):
    with FakeOpenAIServer([first]) as server:
        backend = create_backend(
            "openai/test-model", api_base=server.url, retry=FAST, timeout=timeout, transport=transport
        )
        start = time.perf_counter()
        result = ask(backend)
        elapsed = time.perf_counter() - start
    assert result.ok and result.retries == 1 and len(server.requests) == 2
    if first.headers.get("Retry-After"):
        assert elapsed >= 0.3  # the server's Retry-After is honoured


@pytest.mark.parametrize(
    ("reply", "error", "timeout"),
    [
        (Reply.error(500), "InternalServerError", 30),
        (Reply.error(429), "RateLimitError", 30),
        (Reply(content="x" * 400, truncate=True), "APIConnectionError", 30),
        (Reply(content="late", delay=4), "Timeout", 1),
        (Reply(reset=True), "APIConnectionError", 30),
    ],
    ids=["500", "429", "truncated", "timeout", "reset"],
)
@TRANSPORTS
def test_persistent_failures_end_as_a_recorded_error_class_never_as_text(reply, error, timeout, transport):
    with FakeOpenAIServer(lambda req: reply) as server:
        backend = create_backend(
            "openai/test-model", api_base=server.url, retry=FAST, timeout=timeout, transport=transport
        )
        result = ask(backend)
    assert result.text is None and not result.ok
    assert result.error == error and error in RETRYABLE
    assert result.retries == FAST.max_retries and len(server.requests) == FAST.max_retries + 1
    assert result.error_message and len(result.error_message) <= 301


@TRANSPORTS
def test_non_retryable_request_errors_fail_at_once(transport):
    with FakeOpenAIServer(lambda req: Reply.error(400, "bad image")) as server:
        result = ask(create_backend("openai/test-model", api_base=server.url, retry=FAST, transport=transport))
    assert result.error == "BadRequestError" and result.retries == 0 and len(server.requests) == 1


@TRANSPORTS
def test_an_empty_answer_is_an_error_not_text(transport):
    with FakeOpenAIServer(lambda req: Reply(content="")) as server:
        result = ask(
            create_backend(
                "openai/test-model",
                api_base=server.url,
                retry=RetryPolicy(max_retries=1, base=0.01),
                transport=transport,
            )
        )
    assert result.error == "EmptyResponse" and result.text is None
    assert len(server.requests) == 1 and result.input_tokens == 1000  # not retried; its usage still counts


@TRANSPORTS
def test_a_rejected_key_stops_the_run_and_the_key_is_not_in_the_message(monkeypatch, transport):
    secret = "sk-test-TOPSECRET-0123456789"
    monkeypatch.setenv("OPENAI_API_KEY", secret)
    with FakeOpenAIServer(lambda req: Reply.error(401, f"Incorrect API key provided: {secret}")) as server:
        backend = create_backend(
            "openai/test-model", api_base=server.url, retry=FAST, transport=transport, api_key_env="OPENAI_API_KEY"
        )
        with pytest.raises(FatalBackendError) as info:
            ask(backend)
    assert server.requests[0].headers["authorization"] == f"Bearer {secret}"
    assert secret not in str(info.value) and "AuthenticationError" in str(info.value)


def test_short_message_redacts_keys_and_is_one_line():
    exc = RuntimeError("failed\nwith key sk-abcdef1234567890 and Bearer xyz.123 and api_key=hunter22")
    text = short_message(exc, secrets=("hunter22",))
    assert "\n" not in text and "sk-abcdef" not in text and "xyz.123" not in text and "hunter22" not in text


def test_the_response_cache_serves_repeated_deterministic_requests(tmp_path, image):
    with FakeOpenAIServer() as server:
        cache = ResponseCache(tmp_path / "c.sqlite")
        backend = create_backend("openai/gpt-4o", api_base=server.url, retry=FAST, cache=cache)
        first, second = ask(backend, image=image), ask(backend, image=image)
        other = ask(backend, text="something else", image=image)
        warm = ask(backend, image=image, params=GenerationParams(temperature=0.7))
        asyncio.run(backend.aclose())
    assert len(server.requests) == 3  # second was a hit; temperature 0.7 is never cached
    assert (first.cached, second.cached, other.cached, warm.cached) == (False, True, False, False)
    assert second.text == first.text and second.input_tokens == first.input_tokens
    assert second.cost_cents == 0.0 and second.seconds < first.seconds + 1
    reopened = ResponseCache(tmp_path / "c.sqlite")
    assert len(reopened) == 2 and reopened.hits == 0


def test_retry_delays_grow_exponentially_with_jitter_and_honour_retry_after():
    policy = RetryPolicy(max_retries=5, base=1.0, cap=8.0)
    for k in range(6):
        assert 0.0 <= policy.delay(k) <= min(8.0, 2.0**k)
    assert policy.delay(0, retry_after=3.0) >= 3.0
    assert policy.delay(0, retry_after=100.0) <= 8.0
    assert policy.should_retry("RateLimitError", 4) and not policy.should_retry("RateLimitError", 5)
    assert not policy.should_retry("BadRequestError", 0)


def test_rate_limiter_queues_requests_beyond_the_per_minute_budget():
    limiter = RateLimiter(rpm=600)  # 10 per second, a burst of 600 allowed

    async def burst(n):
        start = time.monotonic()
        await asyncio.gather(*(limiter.acquire() for _ in range(n)))
        return time.monotonic() - start

    assert asyncio.run(burst(600)) < 0.2
    assert 0.4 <= asyncio.run(burst(5)) < 1.5  # bucket empty: 5 more take ~0.5 s


def test_rate_limiter_token_budget_and_settlement():
    limiter = RateLimiter(tpm=60_000)  # 1000 tokens per second

    async def go():
        await limiter.acquire(60_000)
        limiter.settle(60_000, 59_500)  # 500 tokens came back
        start = time.monotonic()
        await limiter.acquire(500)
        fast = time.monotonic() - start
        start = time.monotonic()
        await limiter.acquire(300)
        return fast, time.monotonic() - start

    fast, slow = asyncio.run(go())
    assert fast < 0.05 and 0.2 <= slow < 1.0


def test_a_call_without_reported_usage_keeps_its_token_reservation():
    """Unknown usage is not zero usage: the estimate stays taken from the TPM bucket."""
    from lightemma.backends.api import ESTIMATED_TOKENS_PER_CALL

    no_usage = {
        "choices": [{"index": 0, "message": {"role": "assistant", "content": "a street"}, "finish_reason": "stop"}]
    }
    with FakeOpenAIServer([Reply(body=no_usage)]) as server:
        backend = create_backend("openai/m", api_base=server.url, retry=FAST, transport="direct", tpm=60_000)
        result = ask(backend)
    assert result.ok and (result.input_tokens, result.output_tokens) == (None, None)
    level = backend.limiter.tokens.level  # refills at 1000 tokens/s; the call takes well under a second
    assert level <= 60_000 - ESTIMATED_TOKENS_PER_CALL + 1000


def test_server_pause_holds_every_caller():
    limiter = RateLimiter()

    async def go():
        limiter.pause(0.3)
        start = time.monotonic()
        await limiter.acquire()
        return time.monotonic() - start

    assert asyncio.run(go()) >= 0.28


NATIVE = [
    ("anthropic/claude-sonnet-4-6", "ANTHROPIC_API_KEY", "/v1/messages", (1000 * 3e-6 + 50 * 1.5e-5) * 100),
    ("claude-3.7-sonnet", "ANTHROPIC_API_KEY", "/v1/messages", (1000 * 3e-6 + 50 * 15e-6) * 100),  # registry price
    (
        "gemini/gemini-2.5-flash",
        "GEMINI_API_KEY",
        "/models/gemini-2.5-flash:generateContent",
        (1000 * 3e-7 + 50 * 2.5e-6) * 100,
    ),
    (
        "Gemini-2.0-Flash",
        "GEMINI_API_KEY",
        "/models/gemini-2.0-flash:generateContent",
        (1000 * 0.1e-6 + 50 * 0.4e-6) * 100,
    ),
]


@pytest.mark.parametrize(("model", "variable", "path", "cost"), NATIVE, ids=[n[0] for n in NATIVE])
def test_native_provider_protocols_through_litellm(monkeypatch, image, model, variable, path, cost):
    monkeypatch.setenv(variable, "native-test-key-0123456789")
    with FakeOpenAIServer([Reply.error(429, retry_after=0.05)]) as server:
        backend = create_backend(model, api_base=server.root_url, retry=FAST)
        result = ask(backend, image=image)
    assert result.ok and result.text.startswith("A two-lane") and result.retries == 1
    assert (result.input_tokens, result.output_tokens) == (1000, 50)
    assert result.cost_cents == pytest.approx(cost)
    req = server.requests[-1]
    assert req.path.split("?")[0].endswith(path) and req.has_image and req.text == "describe"
    # a reasoning model (Gemini 2.5) gets its reasoning budget on top of the answer's 512 tokens
    expected = 512 + backend.reasoning_budget
    assert backend.reasoning_budget == (DEFAULT_REASONING_BUDGET if "2.5" in model else 0)
    if req.protocol == "anthropic":
        assert req.body["temperature"] == 0 and req.body["max_tokens"] == expected
    else:
        config = req.body["generationConfig"]
        assert (
            config["temperature"] == 0 and config.get("maxOutputTokens", config.get("max_output_tokens")) == expected
        ), config


@pytest.mark.parametrize(
    ("model", "variable", "reasoning"),
    [
        ("gemini/gemini-2.5-flash", "GEMINI_API_KEY", 300),
        ("anthropic/claude-sonnet-4-6", "ANTHROPIC_API_KEY", 0),
        ("openai/m", None, 300),
    ],
)
def test_every_protocol_reports_why_generation_stopped_and_the_reasoning_tokens(
    monkeypatch, model, variable, reasoning
):
    if variable:
        monkeypatch.setenv(variable, "native-test-key-0123456789")
    replies = [
        Reply("cut off", finish_reason="length", completion_tokens=512, reasoning_tokens=reasoning or None),
        Reply("whole", finish_reason="stop"),
    ]
    with FakeOpenAIServer(replies) as server:
        backend = create_backend(
            model, api_base=server.url if model.startswith("openai/") else server.root_url, retry=FAST
        )
        cut, whole = ask(backend), ask(backend)
    assert (cut.text, cut.finish_reason, cut.output_tokens, cut.reasoning_tokens) == (
        "cut off",
        "length",
        512,
        reasoning,
    )
    assert (whole.text, whole.finish_reason) == ("whole", "stop")


def test_direct_transport_needs_an_openai_compatible_endpoint():
    with pytest.raises(UserError, match="transport 'direct' needs --api-base"):
        create_backend("anthropic/claude-sonnet-4-6", api_base="http://127.0.0.1:9", transport="direct", api_key="x")
    with pytest.raises(UserError, match="unknown transport"):
        create_backend("openai/m", api_base="http://127.0.0.1:9/v1", transport="carrier-pigeon")


def test_the_image_cache_reads_each_image_once_and_stays_within_its_byte_budget(tmp_path):
    from lightemma.backends.api import _ImageCache

    paths = []
    for i in range(5):
        path = tmp_path / f"{i}.png"
        path.write_bytes(bytes([i]) * 300)  # same size each; the cache never decodes
        paths.append(str(path))
    one = len(_ImageCache().get(paths[0])[0])
    cache = _ImageCache(max_bytes=3 * one)
    first = cache.get(paths[0])
    assert first[0].startswith("data:image/png;base64,") and cache.get(paths[0]) is first
    for p in paths[1:]:
        cache.get(p)
    assert cache.bytes <= 3 * one and len(cache._items) == 3 and paths[0] not in cache._items
