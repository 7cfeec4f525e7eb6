"""litellm, imported the one way lightemma wants it: bundled price list, no telemetry, quiet.

Without ``LITELLM_LOCAL_MODEL_COST_MAP`` litellm fetches its price list over
the network at import (seconds of retries when offline); lightemma uses the
list bundled with the pinned litellm, so prices are reproducible per version.
Likewise for the Anthropic beta-header table (which structured outputs and
prompt caching consult): the bundled copy, never a fetch at call time.
"""

from __future__ import annotations

import os

os.environ.setdefault("LITELLM_LOCAL_MODEL_COST_MAP", "True")
os.environ.setdefault("LITELLM_LOCAL_ANTHROPIC_BETA_HEADERS", "True")

import litellm  # noqa: E402  (after the environment default above)

litellm.suppress_debug_info = True
litellm.telemetry = False

__all__ = ["litellm"]
