"""The micro-batcher shared by the local backends: batching, stage grouping, ordering, errors, shutdown."""

import asyncio
import threading
import time

import pytest

from lightemma.backends.base import ChatRequest, ChatResult, GenerationParams
from lightemma.backends.batching import MicroBatcher


def req(i, stage="scene", max_tokens=512):
    return ChatRequest(
        text=f"prompt {i}", stage=stage, frame_id=f"f{i}", params=GenerationParams(max_tokens=max_tokens)
    )


class Recorder:
    """A ``run_batch`` that echoes each prompt and records the batches (and the thread) it ran on.

    While ``gate`` is clear the first batch blocks, so that later requests pile up in the queue.
    """

    def __init__(self, *, block_first=False, fail_when=None):
        self.batches = []
        self.threads = set()
        self.gate = threading.Event()
        self.started = threading.Event()
        if not block_first:
            self.gate.set()
        self.fail_when = fail_when

    def __call__(self, requests):
        self.threads.add(threading.current_thread().name)
        self.batches.append([(r.stage, r.text) for r in requests])
        self.started.set()
        self.gate.wait(5)
        if self.fail_when and self.fail_when(requests):
            raise MemoryError("CUDA out of memory. Tried to allocate 2.00 GiB")
        return [
            ChatResult(text=f"echo {r.text}", input_tokens=len(r.text), output_tokens=len(requests), seconds=0.0)
            for r in requests
        ]


async def fill_while_blocked(batcher, recorder, first, rest):
    """Submit ``first`` alone, wait until the worker is busy with it, submit ``rest``, then release."""
    t0 = asyncio.create_task(batcher.submit(first))
    await asyncio.to_thread(recorder.started.wait, 5)
    tasks = [asyncio.create_task(batcher.submit([r])) for r in rest]
    await asyncio.sleep(0.05)  # every request is queued before the worker is free again
    recorder.gate.set()
    out = [await t0] + [await t for t in tasks]
    await batcher.aclose()
    return out


def test_concurrent_requests_are_answered_in_batches_of_batch_size_each_with_its_own_result():
    rec = Recorder(block_first=True)
    batcher = MicroBatcher(rec, batch_size=4, batch_window=0.5)
    out = asyncio.run(fill_while_blocked(batcher, rec, [req(0)], [req(i) for i in range(1, 10)]))
    assert [len(b) for b in rec.batches] == [1, 4, 4, 1]
    assert [r[0].text for r in out[:1]] + [r[0].text for r in out[1:]] == [f"echo prompt {i}" for i in range(10)]
    # arrival order is kept inside and across batches
    assert [t for b in rec.batches for _, t in b] == [f"prompt {i}" for i in range(10)]
    assert batcher.stats.to_dict() == {
        "batches": 4,
        "requests": 10,
        "seconds": pytest.approx(batcher.stats.seconds, abs=1e-3),
        "mean_batch_size": 2.5,
        "max_batch_size": 4,
    }


def test_a_batch_never_mixes_stages_and_starts_from_the_oldest_pending_stage():
    rec = Recorder(block_first=True)
    batcher = MicroBatcher(rec, batch_size=4, batch_window=0.5)
    rest = [
        req(1, "intent"),
        req(2, "intent"),
        req(3, "scene"),
        req(4, "scene"),
        req(5, "scene"),
        req(6, "intent"),
        req(7, "actions"),
        req(8, "intent"),
        req(9, "intent"),
    ]
    asyncio.run(fill_while_blocked(batcher, rec, [req(0, "scene")], rest))
    stages = [[s for s, _ in b] for b in rec.batches]
    assert stages == [["scene"], ["intent"] * 4, ["scene"] * 3, ["actions"], ["intent"]]
    assert [t for _, t in rec.batches[1]] == ["prompt 1", "prompt 2", "prompt 6", "prompt 8"]


def test_requests_with_different_generation_params_are_not_batched_together():
    rec = Recorder(block_first=True)
    batcher = MicroBatcher(rec, batch_size=8, batch_window=0.5)
    rest = [req(1, max_tokens=16), req(2, max_tokens=32), req(3, max_tokens=16)]
    asyncio.run(fill_while_blocked(batcher, rec, [req(0)], rest))
    assert [[t for _, t in b] for b in rec.batches] == [["prompt 0"], ["prompt 1", "prompt 3"], ["prompt 2"]]


def test_batch_size_one_runs_every_request_alone_on_one_worker_thread():
    rec = Recorder()
    batcher = MicroBatcher(rec, batch_size=1, batch_window=0.05, name="model-owner")

    async def main():
        out = await asyncio.gather(*(batcher.submit([req(i)]) for i in range(5)))
        await batcher.aclose()
        return out

    out = asyncio.run(main())
    assert [len(b) for b in rec.batches] == [1] * 5
    assert [o[0].text for o in out] == [f"echo prompt {i}" for i in range(5)]
    assert rec.threads == {"model-owner"}


def test_one_call_with_several_requests_returns_them_in_order():
    rec = Recorder()
    batcher = MicroBatcher(rec, batch_size=3, batch_window=0.2)

    async def main():
        out = await batcher.submit([req(i) for i in range(7)])
        await batcher.aclose()
        return out

    out = asyncio.run(main())
    assert [r.text for r in out] == [f"echo prompt {i}" for i in range(7)]
    assert [len(b) for b in rec.batches] == [3, 3, 1]


def test_a_lone_request_waits_only_the_batch_window():
    rec = Recorder()
    batcher = MicroBatcher(rec, batch_size=64, batch_window=0.05)

    async def main():
        start = time.perf_counter()
        out = await batcher.submit([req(0)])
        elapsed = time.perf_counter() - start
        await batcher.aclose()
        return out, elapsed

    out, elapsed = asyncio.run(main())
    assert out[0].text == "echo prompt 0"
    assert 0.04 <= elapsed < 1.0


def test_a_failing_batch_gives_every_request_an_error_result_and_the_worker_goes_on():
    rec = Recorder(fail_when=lambda rs: any(r.text == "prompt 1" for r in rs))
    batcher = MicroBatcher(rec, batch_size=2, batch_window=0.2)

    async def main():
        first = await batcher.submit([req(0), req(1)])
        second = await batcher.submit([req(2)])
        await batcher.aclose()
        return first, second

    first, second = asyncio.run(main())
    assert [(r.text, r.error, r.ok) for r in first] == [(None, "MemoryError", False)] * 2
    assert "out of memory" in first[0].error_message
    assert first[0] is not first[1]
    assert second[0].text == "echo prompt 2"


def test_a_batch_ending_its_thread_still_answers_its_requests():
    """A BaseException (SystemExit from a library, say) ends the worker, but no request waits forever."""
    calls = []

    def run_batch(requests):
        calls.append(len(requests))
        if len(calls) == 1:
            raise SystemExit("engine gone")
        return [ChatResult(text="fine") for _ in requests]

    batcher = MicroBatcher(run_batch, batch_size=2, batch_window=0.05)

    async def main():
        first = await asyncio.wait_for(batcher.submit([req(0), req(1)]), 5)
        second = await asyncio.wait_for(batcher.submit([req(2)]), 5)  # a new worker takes over
        await batcher.aclose()
        return first, second

    first, second = asyncio.run(main())
    assert [r.error for r in first] == ["SystemExit", "SystemExit"]
    assert "engine gone" in first[0].error_message
    assert second[0].text == "fine"


def test_a_run_batch_returning_the_wrong_number_of_results_is_an_error_not_a_misalignment():
    batcher = MicroBatcher(lambda rs: [ChatResult(text="only one")], batch_size=2, batch_window=0.2)

    async def main():
        out = await batcher.submit([req(0), req(1)])
        await batcher.aclose()
        return out

    out = asyncio.run(main())
    assert [r.error for r in out] == ["RuntimeError", "RuntimeError"]
    assert "2 requests" in out[0].error_message


def test_one_batcher_serves_successive_event_loops_and_close_stops_its_thread():
    rec = Recorder()
    batcher = MicroBatcher(rec, batch_size=2, batch_window=0.01)
    assert asyncio.run(batcher.submit([req(0)]))[0].text == "echo prompt 0"
    assert asyncio.run(batcher.submit([req(1)]))[0].text == "echo prompt 1"  # a second asyncio.run (a resume)
    thread = batcher._thread
    assert thread.is_alive()
    asyncio.run(batcher.aclose())
    assert not thread.is_alive()
    with pytest.raises(RuntimeError, match="closed"):
        asyncio.run(batcher.submit([req(2)]))


def test_close_while_requests_wait_answers_them_with_an_error():
    rec = Recorder(block_first=True)
    batcher = MicroBatcher(rec, batch_size=1, batch_window=0.0)

    async def main():
        first = asyncio.create_task(batcher.submit([req(0)]))
        await asyncio.to_thread(rec.started.wait, 5)
        waiting = asyncio.create_task(batcher.submit([req(1)]))
        await asyncio.sleep(0.02)
        closing = asyncio.create_task(batcher.aclose())
        await asyncio.sleep(0.02)
        rec.gate.set()
        await closing
        return await first, await waiting

    first, waiting = asyncio.run(main())
    assert first[0].text == "echo prompt 0"  # the running batch finishes
    assert waiting[0].error == "RuntimeError" and "closed" in waiting[0].error_message


def test_a_cancelled_request_is_dropped_from_its_batch():
    rec = Recorder(block_first=True)
    batcher = MicroBatcher(rec, batch_size=4, batch_window=0.2)

    async def main():
        first = asyncio.create_task(batcher.submit([req(0)]))
        await asyncio.to_thread(rec.started.wait, 5)
        doomed = asyncio.create_task(batcher.submit([req(1)]))
        kept = asyncio.create_task(batcher.submit([req(2)]))
        await asyncio.sleep(0.02)
        doomed.cancel()
        await asyncio.sleep(0.02)
        rec.gate.set()
        out = await first, await kept
        await batcher.aclose()
        return out

    first, kept = asyncio.run(main())
    assert kept[0].text == "echo prompt 2"
    assert rec.batches[1] == [("scene", "prompt 2")]


@pytest.mark.parametrize("kwargs, message", [({"batch_size": 0}, "batch_size"), ({"batch_window": -1}, "batch_window")])
def test_bad_settings_are_refused(kwargs, message):
    with pytest.raises(ValueError, match=message):
        MicroBatcher(lambda rs: [], **kwargs)


def test_requests_failed_after_their_caller_was_cancelled_leave_no_unretrieved_exception():
    """A run that stops cancels its frames' tasks, then resolves their queued requests with the stop's error: asyncio must
    not log "Future exception was never retrieved" (it printed a traceback per request after the one-line stop)."""
    import gc

    from lightemma.errors import RunFatalError

    recorder = Recorder(block_first=True)
    batcher = MicroBatcher(
        recorder, batch_size=1, batch_window=0, deadline=30
    )  # a deadline: the watchdog's asyncio.wait
    logged = []

    async def main():
        asyncio.get_running_loop().set_exception_handler(lambda loop, context: logged.append(context.get("message")))
        running = asyncio.ensure_future(
            batcher.submit([req(0)])
        )  # its batch blocks: the next requests wait in the queue
        queued = asyncio.ensure_future(batcher.submit([req(1), req(2)]))
        await asyncio.sleep(0.2)
        queued.cancel()
        with batcher._cond:
            leftover = list(batcher._queue)
            batcher._queue.clear()
        stop = RunFatalError("the run stopped", cause="local-model")
        for pending in leftover:
            MicroBatcher._resolve(pending, stop)
        await asyncio.sleep(0.05)
        del leftover, pending
        recorder.gate.set()
        await running
        await batcher.aclose()

    asyncio.run(main())
    gc.collect()
    assert not [m for m in logged if m and "never retrieved" in m], logged
