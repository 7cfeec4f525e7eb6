"""The one small interface every provider's batch adapter implements, and what it returns.

An adapter turns OpenAI-style chat bodies (``model``, ``messages`` with ``image_url`` data URLs,
``max_tokens``, ``temperature``, ``response_format``) into its provider's batch entries, creates a
batch, reports its state and reads its results back as :class:`ItemResult` dicts keyed by custom id.
It never decides anything about the run: waves, splitting, polling, the journal and resubmission live in
:class:`lightemma.backends.batch.BatchBackend`.
"""

from __future__ import annotations

import json
from collections.abc import Collection, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol, TypedDict

from lightemma.backends.retry import split_credentials

#: states of a batch as lightemma sees it: still running, or one terminal state
PENDING, ENDED, FAILED = "pending", "ended", "failed"

#: what one reply of a batch API may be, decoded (docs/run.md, "Limits"): RESULT_BYTES_PER_REQUEST for every request
#: of the batch it is about (an answer of 64k tokens fits), and never less than MIN_REPLY_BYTES. A status poll, a
#: results file or a listing past it fails that call (the run stops, resumable); an endless or bloated body never
#: fills memory. Online replies have their own limit (:data:`lightemma.backends.openai_http.MAX_BODY_BYTES`).
RESULT_BYTES_PER_REQUEST = 256 << 10
MIN_REPLY_BYTES = 64 << 20


def batch_client(timeout: float, headers: dict[str, str]) -> Any:
    """An adapter's ``httpx.AsyncClient``: every reply read within the limit the call sets
    (:func:`~lightemma.backends.openai_http.body_guard` in :class:`~lightemma.backends.batch.BatchBackend`)."""
    import httpx

    from lightemma.backends.openai_http import body_limit_hooks

    return httpx.AsyncClient(timeout=timeout, headers=headers, event_hooks=body_limit_hooks())


def batch_state(batch_id: str, state: str, terminal: dict[str, str], running: Sequence[str]) -> str:
    """:data:`PENDING`, :data:`ENDED` or :data:`FAILED` for a provider's documented ``state``; a state it does not
    document is a ``ValueError`` (the answer is not used: polling it would never end)."""
    if state in terminal:
        return terminal[state]
    if state in running:
        return PENDING
    raise ValueError(f"batch {batch_id}: state {state[:60]!r} is none of {', '.join([*running, *terminal])}")


#: seconds the provider's clock may run behind this machine's: a look-up reads back this far before a submission
CLOCK_SKEW_S = 600.0
#: the most pages of a provider's batch list one look-up reads (a list that never ends, or never reaches ``since``)
MAX_LIST_PAGES = 1000


def _utf8_over(text: str, limit: int) -> bool:
    """``text`` takes more than ``limit`` bytes as UTF-8 (encoded only when its length allows it)."""
    return len(text) > limit // 4 and len(text.encode("utf-8", "surrogatepass")) > limit


def results_limit(n_requests: int) -> int:
    """The most bytes lightemma reads of one reply about a batch of ``n_requests`` requests (see above)."""
    return max(MIN_REPLY_BYTES, int(n_requests) * RESULT_BYTES_PER_REQUEST)


class BatchHTTPError(Exception):
    """A provider's batch endpoint answered with an error (``status`` 0: no answer at all)."""

    def __init__(self, status: int, message: str, *, answer: bool = False, deadline: bool = False) -> None:
        super().__init__(f"HTTP {status}: {message}" if status else message)
        self.status = status
        self.answer = answer  # the provider answered, with something lightemma must not use (not worth a retry)
        self.deadline = deadline  # no whole answer within --timeout

    @property
    def transient(self) -> bool:
        """Worth retrying: a dropped connection, a rate limit, a server error."""
        return not self.answer and (self.status == 0 or self.status == 429 or self.status >= 500)

    @property
    def auth(self) -> bool:
        return self.status in (401, 403)


class BatchUnconfirmed(Exception):
    """A look-up cannot tell whether a cut-off submission created a batch (a provider without a name to find it by,
    and a batch of the same size created since): lightemma neither creates it again nor takes a stranger's."""


@dataclass
class BatchStatus:
    """Where a batch stands: ``state`` (pending / ended / failed), the provider's own word, counts, a reason.

    ``answered``: how many result lines the provider says it holds (requests it ran, answered or errored, plus
    those it lists as expired or canceled); ``unrun``: how many requests it says got no result line at all
    (Gemini's unreached requests); None where the provider reported no counts. ``canceled``: the batch was
    canceled (in the provider's console or API). ``retryable``: a batch failed as a whole for a reason that
    passes (OpenAI's enqueued-token limit), so its requests may go out again."""

    state: str
    provider_state: str
    counts: dict[str, Any] = field(default_factory=dict)
    reason: str | None = None  # why a batch failed (validation errors, …)
    handle: dict[str, Any] = field(default_factory=dict)  # what reading its results needs (file ids, URLs)
    answered: int | None = None
    unrun: int | None = None
    canceled: bool = False
    retryable: bool = False


def tally(counts: Any, names: Sequence[str]) -> int | None:
    """The sum of the counts ``names`` in a provider's ``counts`` object (missing ones as 0), or None when it is no
    object or any of them is not a non-negative int (unknown, never zero)."""
    if not isinstance(counts, dict) or not any(n in counts for n in names):
        return None
    values = [counts.get(n, 0) for n in names]
    if not all(isinstance(v, int) and not isinstance(v, bool) and v >= 0 for v in values):
        return None
    return sum(values)


class ItemUsage(TypedDict, total=False):
    """The usage keywords of :func:`item_result`, as a provider's result reports them (None = unknown)."""

    finish_reason: str | None
    input_tokens: int | None
    output_tokens: int | None
    reasoning_tokens: int | None
    cached_input_tokens: int | None
    cache_write_tokens: int | None


def item_result(
    custom_id: str,
    *,
    text: str | None = None,
    finish_reason: str | None = None,
    input_tokens: int | None = None,
    output_tokens: int | None = None,
    reasoning_tokens: int | None = None,
    cached_input_tokens: int | None = None,
    cache_write_tokens: int | None = None,
    error: str | None = None,
    error_message: str | None = None,
    resubmit: bool = False,
) -> dict[str, Any]:
    """One request's result as saved in ``batches/<id>.jsonl``: text or error, usage as reported (None = unknown).

    ``resubmit``: the provider never ran it (expired, canceled): it may be sent again in a new batch.
    """
    return {
        "custom_id": custom_id,
        "text": text,
        "finish_reason": finish_reason,
        "input_tokens": input_tokens,
        "output_tokens": output_tokens,
        "reasoning_tokens": reasoning_tokens,
        "cached_input_tokens": cached_input_tokens,
        "cache_write_tokens": cache_write_tokens,
        "error": error,
        "error_message": error_message,
        "resubmit": resubmit,
    }


async def http_call(client: Any, method: str, url: str, **kw: Any) -> Any:
    """One request on an ``httpx.AsyncClient``; the response, or :class:`BatchHTTPError` with the provider's message."""
    import httpx

    try:
        response = await client.request(method, url, **kw)
    except httpx.HTTPError as exc:
        raise BatchHTTPError(0, f"{type(exc).__name__}: {exc}") from None
    if 300 <= response.status_code < 400 or response.status_code < 200:  # the key is not sent on to another place
        raise BatchHTTPError(
            response.status_code,
            f"{method} answered with HTTP {response.status_code} "
            f"(to {str(response.headers.get('location'))[:120]!r}), not an answer; lightemma follows no "
            "redirect of a batch API",
            answer=True,
        )
    if response.status_code >= 400:
        try:
            message = response.json().get("error", {}).get("message") or response.text[:300]
        except (ValueError, AttributeError):
            message = response.text[:300]
        raise BatchHTTPError(response.status_code, str(message))
    return response


def endpoint(
    api_base: str | None, default: str, api_key: str | None, *, key_header: str, version: str
) -> tuple[str, dict[str, str]]:
    """The base URL and headers of a provider's batch HTTP API.

    The base is ``api_base`` without credentials and a trailing ``version`` (``/v1``, ``/v1beta``; ``""``: the path
    kept, as OpenAI's bases end in ``/v1``), else
    ``default``; the headers carry ``api_key`` — the key the run's API backend decided to send, None for none —
    in ``key_header``, and ``user:pw@`` of ``api_base`` as Basic auth. No key is read from the environment here.
    """
    url, basic = split_credentials(api_base) if api_base else (default, None)
    url = url.rstrip("/")
    if version and url.endswith(version):
        url = url[: -len(version)]
    headers = {key_header: api_key} if api_key else {}
    if basic:
        headers["Authorization"] = basic
    return url, headers


def count(usage: dict[str, Any], name: str) -> int | None:
    """A token count a provider reported: a non-negative int, else None (unknown, never zero)."""
    value = usage.get(name)
    return value if isinstance(value, int) and not isinstance(value, bool) and value >= 0 else None


def checked_results(items: list[dict[str, Any]], custom_ids: Sequence[str]) -> list[dict[str, Any]]:
    """A batch's results as lightemma uses them, or :class:`BatchHTTPError` (an answer not to use): every result for
    a request of the batch (``custom_ids``), none twice — lightemma does not choose between two answers, nor take one
    for a request it never sent. An answer text over the reply limit
    (:data:`~lightemma.backends.openai_http.MAX_BODY_BYTES`, as an online reply) is that request's
    ``ResponseTooLargeError``, not kept."""
    from lightemma.backends.openai_http import MAX_BODY_BYTES

    wanted, seen = set(custom_ids), set()
    for i, item in enumerate(items):
        cid = item.get("custom_id")
        if not isinstance(cid, str) or cid not in wanted:
            raise BatchHTTPError(
                0, f"the results answer {str(cid)[:80]!r}, which is no request of this batch", answer=True
            )
        if cid in seen:
            raise BatchHTTPError(0, f"the results hold request {cid} twice; lightemma does not choose one", answer=True)
        seen.add(cid)
        text = item.get("text")
        if isinstance(text, str) and _utf8_over(text, MAX_BODY_BYTES):
            items[i] = {
                **item,
                "text": None,
                "error": "ResponseTooLargeError",
                "resubmit": False,
                "error_message": f"the answer is over {MAX_BODY_BYTES:,} bytes, more than lightemma reads",
            }
    return items


def jsonl_rows(data: bytes, where: str) -> Iterator[dict[str, Any]]:
    """The JSON objects of a JSONL results file, one line at a time (parsed lines are not held: a line of ``[{},{},…]``
    grows ~30× in memory). A line over the online reply limit plus 1 MiB of envelope, one that is not a JSON object,
    or a file that is not UTF-8: :class:`BatchHTTPError` (an answer not to use)."""
    from lightemma.backends.openai_http import MAX_BODY_BYTES

    limit = MAX_BODY_BYTES + (1 << 20)
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        raise BatchHTTPError(0, f"{where}: the results are not UTF-8 text", answer=True) from None
    for number, line in enumerate(text.split("\n"), 1):  # "\n" only: U+2028, U+0085 are text inside a JSON string
        if not line.strip():
            continue
        if _utf8_over(line, limit):
            raise BatchHTTPError(
                0, f"{where}: results line {number} is over {limit:,} bytes, more than one answer may be", answer=True
            )
        try:
            row = json.loads(line)
        except (json.JSONDecodeError, RecursionError) as exc:
            raise BatchHTTPError(
                0, f"{where}: results line {number} is not JSON ({type(exc).__name__})", answer=True
            ) from None
        if not isinstance(row, dict):
            raise BatchHTTPError(0, f"{where}: results line {number} is not a JSON object", answer=True)
        yield row


def url_id(value: Any, *, slash: bool = False) -> str:
    """A provider's id (a batch's, a file's) as one piece of a URL path: percent-quoted, so an id never moves a call to
    another path or query; ``slash``: ids of the form ``batches/123`` (Gemini), without ``.`` or ``..`` segments."""
    from urllib.parse import quote

    text = str(value)
    if slash and any(part in ("", ".", "..") for part in text.split("/")):
        raise BatchHTTPError(0, f"the id {text[:80]!r} is not an id lightemma puts in a URL", answer=True)
    return quote(text, safe="/" if slash else "")


def entry_bytes(entry: Any) -> int:
    """Bytes one entry takes in a batch (its JSON line)."""
    return len(json.dumps(entry, separators=(",", ":"), ensure_ascii=False).encode("utf-8")) + 1


def split_data_url(url: str) -> tuple[str, str]:
    """(mime type, base64 data) of a ``data:<mime>;base64,<data>`` URL."""
    head, _, data = url.partition(",")
    mime = head[5:].split(";", 1)[0] if head.startswith("data:") else "image/jpeg"
    return mime or "image/jpeg", data


class BatchAdapter(Protocol):
    """One provider's batch interface (see the module docstring)."""

    provider: str
    max_requests: int  # requests per batch the provider accepts
    max_bytes: int  # bytes per batch (input file or request body) the provider accepts

    def entry(self, custom_id: str, body: dict[str, Any]) -> dict[str, Any]:
        """The provider's batch entry for one OpenAI-style chat body."""
        ...

    async def submit(self, entries: list[dict[str, Any]], token: str) -> str:
        """Create a batch of ``entries`` named/tagged ``token``; its id."""
        ...

    async def status(self, batch_id: str) -> BatchStatus: ...

    async def results(self, batch_id: str, status: BatchStatus) -> list[dict[str, Any]]:
        """Every result of an ended batch (:func:`item_result` dicts), in whatever order the provider gives them."""
        ...

    async def find(self, token: str, since: float, n_requests: int, known: Collection[str] = ()) -> str | None:
        """The id of a batch created with ``token`` (a submission whose answer was lost, or cut off before its id was
        journaled), else None: every page of the provider's batch list is read, newest first, down to batches
        created before ``since`` (the local time the submission was journaled, less :data:`CLOCK_SKEW_S`); ``known``:
        this run's journaled batch ids.
        :class:`BatchUnconfirmed` when the provider cannot tell (see there)."""
        ...

    async def aclose(self) -> None: ...
