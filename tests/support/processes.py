"""Processes seen through /proc (Linux): what the signal and worker tests of import and run look at."""

from __future__ import annotations

import time
from pathlib import Path


def children(pid: int) -> list[int]:
    """The child pids of ``pid``, across its threads."""
    kids: list[int] = []
    for f in Path(f"/proc/{pid}/task").glob("*/children"):
        kids += [int(p) for p in f.read_text().split()]
    return kids


def still_running(pids: list[int], seconds: float = 0.0) -> list[int]:
    """The pids still running (not zombies) after waiting up to ``seconds`` for them to end (0: look once)."""
    deadline = time.monotonic() + seconds
    while True:
        alive = []
        for pid in pids:
            try:
                state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
            except (FileNotFoundError, ProcessLookupError):
                continue
            if state not in ("Z", "X"):
                alive.append(pid)
        if not alive or time.monotonic() > deadline:
            return alive
