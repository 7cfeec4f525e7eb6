"""Shared test setup: no network for Hugging Face or litellm's price list."""

import os
import sys
from pathlib import Path

os.environ["HF_HUB_OFFLINE"] = "1"
os.environ["LITELLM_LOCAL_MODEL_COST_MAP"] = "True"

# fake_openai.py lives beside the tests and is imported by them as a module
sys.path.insert(0, str(Path(__file__).parent))

import pytest  # noqa: E402


@pytest.fixture(scope="session")
def synth_root(tmp_path_factory):
    """A small synthetic nuScenes dataset (v1.0-mini, 2 scenes × 20 keyframes → 12 reference frames)."""
    from lightemma.synth import write_dataset

    return write_dataset(tmp_path_factory.mktemp("synth"), scenes=2, keyframes=20, image_size=(64, 36), sweeps=False)
