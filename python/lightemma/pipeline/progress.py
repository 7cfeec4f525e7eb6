"""The progress bar of a run: frames done, frames/s, ETA (tqdm), plus failures, API errors and cost."""

from __future__ import annotations

import sys
from typing import Any


class Progress:
    """A tqdm bar over frames; ``update(record)`` after each finished frame."""

    def __init__(self, total: int, *, enabled: bool = True, initial: int = 0, desc: str = "frames") -> None:
        from tqdm import tqdm

        self.failed = 0
        self.errors = 0
        self.cost_cents = 0.0
        self._bar = tqdm(
            total=total,
            initial=initial,
            unit="frame",
            desc=desc,
            disable=not enabled,
            file=sys.stderr,
            dynamic_ncols=True,
            mininterval=0.5,
            smoothing=0.05,
        )

    def update(self, record: dict[str, Any]) -> None:
        self.failed += record["status"] == "failed"
        self.errors += sum(1 for a in record["attempts"] for c in a["calls"] if c["error"])
        self.cost_cents += record["cost_cents"] or 0.0
        self._bar.set_postfix_str(
            f"failed={self.failed} errors={self.errors} cost=${self.cost_cents / 100:.2f}", refresh=False
        )
        self._bar.update(1)

    def close(self) -> None:
        self._bar.close()
