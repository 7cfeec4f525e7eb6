"""Stop signals, handled alike by ``lightemma run`` and ``lightemma import``.

SIGINT, SIGTERM and SIGHUP (what Ctrl-C, Slurm, Kubernetes, systemd and a closed terminal send first) raise
:class:`~lightemma.errors.Interrupted`, so a command stops as on Ctrl-C: it records what it did, cleans up and says so
in one line. Loaded by both commands; it imports nothing heavy.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

from lightemma.errors import STOP_SIGNALS, Interrupted


def interrupt_on_stop_signals() -> None:
    """From a command's first line: SIGTERM and SIGHUP raise :class:`Interrupted`, as SIGINT raises KeyboardInterrupt
    (before a command's own handlers are in place they killed the process with no line and files left behind).
    Nothing is changed outside the main thread."""
    if threading.current_thread() is not threading.main_thread():
        return  # called from Python in another thread: signals are the main thread's

    def stop(signum: int, frame: Any) -> None:
        raise Interrupted(signum)

    for sig in STOP_SIGNALS:
        if sig != signal.SIGINT:
            signal.signal(sig, stop)


@contextmanager
def stop_signals(again: Callable[[int], None]) -> Iterator[None]:
    """While the block runs: a stop signal raises :class:`Interrupted` (the caller stops and cleans up); a second one
    while that is under way calls ``again(signum)``, which must end the process at once (``os._exit``). The handlers
    in place before are put back after. Nothing is changed outside the main thread."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    received: list[int] = []

    def handler(signum: int, frame: Any) -> None:
        received.append(signum)
        if len(received) > 1:
            again(signum)
        raise Interrupted(signum)

    previous = {sig: signal.signal(sig, handler) for sig in STOP_SIGNALS}
    try:
        yield
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)
