"""Shared test setup: no network for Hugging Face or litellm's price list."""

import os
import sys
from pathlib import Path

os.environ["HF_HUB_OFFLINE"] = "1"
os.environ["LITELLM_LOCAL_MODEL_COST_MAP"] = "True"

# fake_openai.py lives beside the tests and is imported by them as a module
sys.path.insert(0, str(Path(__file__).parent))
