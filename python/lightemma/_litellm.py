"""litellm, imported the one way lightemma wants it: bundled price list, no telemetry, quiet.

Without ``LITELLM_LOCAL_MODEL_COST_MAP`` litellm fetches its price list over
the network at import (seconds of retries when offline); lightemma uses the
list bundled with the pinned litellm, so prices are reproducible per version.
Likewise for the Anthropic beta-header table (which structured outputs and
prompt caching consult): the bundled copy, never a fetch at call time.

Importing this module does not import litellm (that takes seconds):
``from lightemma._litellm import litellm`` does, at that line; ``lazy`` stands for
the module and imports it at its first attribute read, for modules that need
litellm only on some paths (the direct transport and the baselines never do).
"""

from __future__ import annotations

import os
from types import ModuleType
from typing import Any

os.environ.setdefault("LITELLM_LOCAL_MODEL_COST_MAP", "True")
os.environ.setdefault("LITELLM_LOCAL_ANTHROPIC_BETA_HEADERS", "True")


def _load() -> ModuleType:
    import litellm

    litellm.suppress_debug_info = True
    litellm.telemetry = False
    globals()["litellm"] = litellm
    return litellm


def __getattr__(name: str) -> Any:
    if name == "litellm":
        return _load()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


class _Lazy:
    """litellm, imported at the first attribute read."""

    def __getattr__(self, name: str) -> Any:
        module = globals().get("litellm") or _load()
        return getattr(module, name)


lazy = _Lazy()

__all__ = ["lazy", "litellm"]
