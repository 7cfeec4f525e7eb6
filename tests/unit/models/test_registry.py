"""The model registry and the backend factory's routing."""

import sys
import types

import litellm
import pytest

from lightemma.backends import backend_kind, create_backend
from lightemma.backends.api import litellm_model, require_api_key
from lightemma.errors import UserError
from lightemma.models.catalog import BASELINES, PAPER_MODELS, lookup, resolve
from lightemma.models.prices import price_per_token

# Display names exactly as in the paper's Tables I and II, in table order.
PAPER_NAMES = [
    "GPT-4o",
    "GPT-5.0",
    "GPT-5.2",
    "Claude-3.7-Sonnet",
    "Claude-4.0-Sonnet",
    "Claude-4.6-Sonnet",
    "Gemini-2.0-Flash",
    "Gemini-2.5-Flash",
    "Gemini-3.0-Flash",
    "Qwen-2.0-VL-7B",
    "Qwen-2.5-VL-7B",
    "Qwen-3.0-VL-8B",
    "LLaMA-3.2-11B",
    "LLaMA-3.2-90B",
    "LLaMA-4.0-17B-Scout",
]
PAPER_GPUS = {
    "Qwen-2.0-VL-7B": 1,
    "Qwen-2.5-VL-7B": 1,
    "Qwen-3.0-VL-8B": 1,
    "LLaMA-3.2-11B": 1,
    "LLaMA-3.2-90B": 3,
    "LLaMA-4.0-17B-Scout": 3,
}


def test_the_fifteen_paper_models_in_table_order_with_generations():
    assert [m.display_name for m in PAPER_MODELS] == PAPER_NAMES
    for family in ("GPT", "Claude", "Gemini", "Qwen", "LLaMA"):
        assert [m.generation for m in PAPER_MODELS if m.family == family] == [1, 2, 3]
    assert {m.display_name: m.gpus for m in PAPER_MODELS if m.backend != "api"} == PAPER_GPUS
    assert all(m.gpus == 0 for m in PAPER_MODELS if m.backend == "api")


def test_api_ids_are_in_litellms_price_list_or_carry_a_dated_provider_price():
    for m in PAPER_MODELS:
        if m.backend != "api":
            continue
        entry = litellm.model_cost.get(m.model_id) or litellm.model_cost.get(m.model_id.split("/", 1)[-1])
        if entry is not None:
            assert entry["litellm_provider"] == litellm.get_llm_provider(m.model_id)[1], m.model_id
            assert entry.get("supports_vision"), f"{m.model_id} is not a vision model in litellm's list"
        else:
            assert m.input_usd_per_mtok and m.output_usd_per_mtok and m.price_source and m.price_read, m.display_name
        assert price_per_token(m) is not None


def test_local_models_are_hugging_face_checkpoints_per_spec():
    assert lookup("Qwen-2.5-VL-7B").model_id == "Qwen/Qwen2.5-VL-7B-Instruct"
    assert lookup("LLaMA-4.0-17B-Scout").model_id == "meta-llama/Llama-4-Scout-17B-16E-Instruct"


def test_lookup_by_key_display_name_or_provider_id_and_ad_hoc_strings():
    assert resolve("gpt-4o") is resolve("GPT-4o") is resolve("gpt-4o ")
    assert resolve("anthropic/claude-3-7-sonnet-20250219").display_name == "Claude-3.7-Sonnet"
    other = resolve("openai/my-finetune")
    assert (other.backend, other.family, other.model_id, other.in_paper) == (
        "api",
        "other",
        "openai/my-finetune",
        False,
    )
    with pytest.raises(UserError, match="baseline:constant"):
        resolve("baseline:nope")


def test_baselines_are_listed_and_need_no_key():
    assert [b.key for b in BASELINES] == ["baseline:constant", "baseline:cv", "baseline:oracle", "baseline:ego"]
    assert all(b.family == "baseline" and not b.needs_api_key for b in BASELINES)


def test_backend_kind_routing():
    assert backend_kind("baseline:cv") == "baseline"
    assert backend_kind("qwen-2.5-vl-7b") == "hf"
    assert backend_kind("qwen-2.5-vl-7b", api_base="http://127.0.0.1:8000/v1") == "api"
    assert litellm_model(lookup("qwen-2.5-vl-7b"), "http://x/v1") == "openai/Qwen/Qwen2.5-VL-7B-Instruct"
    assert backend_kind("gpt-4o") == "api"
    assert backend_kind("Qwen/Qwen3-VL-8B-Instruct", backend="vllm") == "vllm"
    with pytest.raises(UserError, match="unknown backend"):
        backend_kind("gpt-4o", backend="tpu")


def _fake_module(monkeypatch, name, cls_name):
    calls = []

    class Fake:
        def __init__(self, *args, **kwargs):
            calls.append((args, kwargs))

    module = types.ModuleType(name)
    setattr(module, cls_name, Fake)
    monkeypatch.setitem(sys.modules, name, module)
    return calls


def test_factory_routes_baselines_and_local_backends_lazily(monkeypatch):
    baseline_calls = _fake_module(monkeypatch, "lightemma.backends.baseline", "BaselineBackend")
    hf_calls = _fake_module(monkeypatch, "lightemma.backends.hf", "HFBackend")
    vllm_calls = _fake_module(monkeypatch, "lightemma.backends.vllm", "VLLMBackend")
    create_backend("baseline:oracle")
    create_backend("qwen-3.0-vl-8b", dtype="bfloat16")
    create_backend("llama-3.2-11b", backend="vllm")
    assert baseline_calls == [(("oracle",), {})]
    assert hf_calls == [(("Qwen/Qwen3-VL-8B-Instruct",), {"dtype": "bfloat16"})]
    assert vllm_calls == [(("meta-llama/Llama-3.2-11B-Vision-Instruct",), {})]


def test_a_missing_optional_backend_is_a_clear_error(monkeypatch):
    monkeypatch.setitem(sys.modules, "lightemma.backends.vllm", None)  # import fails
    with pytest.raises(UserError, match=r"VLLMBackend backend is not available.*lightemma\[vllm\]"):
        create_backend("qwen-2.5-vl-7b", backend="vllm")


@pytest.mark.parametrize(
    ("model", "variable"),
    [
        ("gpt-4o", "OPENAI_API_KEY"),
        ("anthropic/claude-sonnet-4-6", "ANTHROPIC_API_KEY"),
        ("gemini/gemini-2.5-flash", "GEMINI_API_KEY"),
    ],
)
def test_missing_api_key_names_the_variable(monkeypatch, model, variable):
    for name in ("OPENAI_API_KEY", "ANTHROPIC_API_KEY", "GEMINI_API_KEY", "GOOGLE_API_KEY"):
        monkeypatch.delenv(name, raising=False)
    with pytest.raises(UserError, match=variable):
        create_backend(model)
    monkeypatch.setenv(variable, "")  # set but empty is missing too
    with pytest.raises(UserError, match=variable):
        create_backend(model)


def test_openai_compatible_endpoint_needs_no_key(elsewhere, monkeypatch):
    monkeypatch.delenv("OPENAI_API_KEY", raising=False)
    assert require_api_key("openai/served-model", "http://127.0.0.1:9/v1")
    monkeypatch.setenv("OPENAI_API_KEY", "sk-local-123456789")
    # the provider's key goes to the provider's own host only; another server gets the key the user names
    assert require_api_key("openai/served-model", "http://127.0.0.1:9/v1") == "sk-no-key-required"
    assert require_api_key("openai/served-model", "http://127.0.0.1:9/v1", "OPENAI_API_KEY") == "sk-local-123456789"


def test_prices_come_from_litellms_bundled_list_without_importing_it():
    from lightemma.models.catalog import PAPER_MODELS
    from lightemma.models.prices import bundled_price_list

    bundled = bundled_price_list()
    assert all(bundled.get(k) == v for k, v in litellm.model_cost.items())  # the same list litellm loads offline
    for m in PAPER_MODELS:
        if m.backend == "api":
            entry = litellm.model_cost.get(m.model_id) or litellm.model_cost.get(m.model_id.split("/", 1)[-1])
            if entry:
                assert price_per_token(m) == (entry["input_cost_per_token"], entry["output_cost_per_token"])


def test_the_registry_knows_which_models_reason_and_agrees_with_litellm():
    from lightemma.models.catalog import DEFAULT_REASONING_BUDGET
    from lightemma.models.prices import reasoning_budget

    reasoning = {m.display_name for m in PAPER_MODELS if m.reasoning}
    assert reasoning == {"GPT-5.0", "GPT-5.2", "Gemini-2.5-Flash", "Gemini-3.0-Flash"}
    for m in PAPER_MODELS:
        assert reasoning_budget(m) == (DEFAULT_REASONING_BUDGET if m.reasoning else 0), m.display_name
        entry = litellm.model_cost.get(m.model_id) or litellm.model_cost.get(m.model_id.split("/", 1)[-1]) or {}
        if m.reasoning:  # where litellm's list knows the model, it says it reasons too
            assert entry.get("supports_reasoning") in (True, None), m.model_id
    # Claude reasons only with extended thinking, which is never requested: no budget, in the registry or ad hoc
    assert reasoning_budget(resolve("anthropic/claude-3-7-sonnet-20250219")) == 0
    assert reasoning_budget(resolve("o3")) == DEFAULT_REASONING_BUDGET  # an ad-hoc reasoning model, per litellm's list
    assert reasoning_budget(resolve("gpt-4o-mini")) == 0


def test_lightemma_models_lists_the_registry_with_prices_their_sources_and_reasoning(capsys):
    import json

    from lightemma.cli import main

    assert main(["models", "--format", "json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    by_key = {r["key"]: r for r in rows}
    assert list(by_key) == [m.key for m in (*PAPER_MODELS, *BASELINES)]
    assert by_key["gpt-4o"]["price_source"].startswith("litellm ") and by_key["gpt-4o"][
        "input_usd_per_mtok"
    ] == pytest.approx(2.5)
    assert by_key["claude-3.7-sonnet"]["price_source"].endswith("read 2026-11-22")
    assert by_key["gpt-5.0"]["reasoning"] and not by_key["gpt-4o"]["reasoning"]
    assert by_key["qwen-2.5-vl-7b"]["backend"] == "hf" and by_key["qwen-2.5-vl-7b"]["input_usd_per_mtok"] is None
    for row in rows:  # the price lightemma charges is the one it lists
        info = lookup(row["key"])
        price = price_per_token(info)
        if price is None:
            assert row["input_usd_per_mtok"] is None
        else:
            assert price == pytest.approx((row["input_usd_per_mtok"] / 1e6, row["output_usd_per_mtok"] / 1e6))
    assert main(["models"]) == 0
    table = capsys.readouterr().out
    assert "| `gpt-5.0` | GPT-5.0 | `gpt-5` | api |" in table and "yes (+8192 output tokens)" in table
    assert "extended thinking not requested" in table


def test_the_paper_tables_family_of_each_row_is_the_catalogs():
    """The paper's tables (leaf data, lightemma.models.paper) name each row's family from the row name; the catalog
    says it too: both must agree for every row, and every paper row must be a catalog model."""
    from lightemma.models.paper import paper_accuracy_rows, paper_efficiency_rows

    catalog = {m.display_name: m.family for m in PAPER_MODELS}
    for rows in (paper_efficiency_rows(), paper_accuracy_rows()):
        assert [r["model"] for r in rows] == PAPER_NAMES
        assert {r["model"]: r["family"] for r in rows} == {name: catalog[name] for name in PAPER_NAMES}


def test_a_paper_row_without_a_known_family_prefix_is_refused():
    from lightemma.models import paper

    with pytest.raises(ValueError, match="no known family prefix"):
        paper._family("Mistral-7B")
