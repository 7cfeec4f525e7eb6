"""Shared test setup: no network for Hugging Face or litellm's price list."""

import os

os.environ["HF_HUB_OFFLINE"] = "1"
os.environ["LITELLM_LOCAL_MODEL_COST_MAP"] = "True"
# The loopback servers of the tests play the providers themselves: a provider's key and its list price apply
# there as on the provider's own host. Tests of what another --api-base gets
# (tests/integration/test_run_hostile.py) clear it.
os.environ["LIGHTEMMA_PROVIDER_HOSTS"] = "openai=127.0.0.1,anthropic=127.0.0.1,gemini=127.0.0.1"

import pytest


@pytest.fixture
def elsewhere(monkeypatch):
    """The loopback servers are just some server, not a provider's own host (see LIGHTEMMA_PROVIDER_HOSTS above)."""
    monkeypatch.delenv("LIGHTEMMA_PROVIDER_HOSTS", raising=False)


@pytest.fixture(scope="session")
def synth_root(tmp_path_factory):
    """A small synthetic nuScenes dataset (v1.0-mini, 2 scenes × 20 keyframes → 12 reference frames)."""
    from lightemma.synth import write_dataset

    return write_dataset(tmp_path_factory.mktemp("synth"), scenes=2, keyframes=20, image_size=(64, 36), sweeps=False)
