"""The frozen Price (lightemma.models.prices.Price): validated once, read as the dict it is recorded as."""

from __future__ import annotations

import dataclasses
import json
import math
import re

import pytest

from lightemma.models.catalog import MODELS, lookup
from lightemma.models.prices import Price, batch_price, list_models, price, run_price

KEYS = ["input_usd_per_mtok", "output_usd_per_mtok", "cache_read_usd_per_mtok", "cache_write_usd_per_mtok", "source"]


def test_every_catalog_price_is_a_valid_frozen_price_recorded_as_before():
    for info in MODELS:
        listed, batch = price(info), batch_price(info)
        assert isinstance(listed, Price) and not listed.batch and list(listed.to_dict()) == KEYS
        assert batch.batch and list(batch.to_dict()) == [*KEYS, "discount"]
        assert dict(listed) == listed.to_dict() and listed["source"] == listed.source
        json.dumps(listed.to_dict())  # recorded as plain JSON
    with pytest.raises(dataclasses.FrozenInstanceError):
        price(lookup("gpt-4o")).source = "elsewhere"  # type: ignore[misc]
    assert all(isinstance(m["price"], dict) and list(m["price"]) == KEYS for m in list_models())


def test_given_and_served_elsewhere_prices_keep_their_shape():
    info = lookup("claude-3.7-sonnet")
    given = run_price(info, batch=True, given=(1.5, 6.0))
    assert given.to_dict() == {
        "input_usd_per_mtok": 1.5,
        "output_usd_per_mtok": 6.0,
        "cache_read_usd_per_mtok": 1.5,
        "cache_write_usd_per_mtok": 1.5,
        "source": "--price 1.5 6 (USD per million input / output tokens)",
    }
    elsewhere = run_price(info, served_from="http://gpu-box:8000/v1")
    assert not elsewhere.known and elsewhere["input_usd_per_mtok"] is None and "discount" not in elsewhere
    assert batch_price(lookup("qwen-2.5-vl-7b")).to_dict()["discount"] is None  # a local model: no price, no discount
    with pytest.raises(KeyError):
        price(info)["discount"]  # an interactive price has no discount


@pytest.mark.parametrize(
    "fields, said",
    [
        (dict(input_usd_per_mtok=-1.0), "input_usd_per_mtok must be a number from 0 to 1e+06 or None, got -1.0"),
        (dict(output_usd_per_mtok=math.inf), "output_usd_per_mtok must be a number"),
        (dict(cache_read_usd_per_mtok=math.nan), "cache_read_usd_per_mtok must be a number"),
        (dict(cache_write_usd_per_mtok=True), "cache_write_usd_per_mtok must be a number"),
        (dict(input_usd_per_mtok="3"), "input_usd_per_mtok must be a number"),
        (dict(output_usd_per_mtok=None), "both its input and output prices or neither"),
        (dict(source=""), "a price needs its source"),
        (dict(discount=0.5), "a discount is a number of at least 0 on a batch price"),
        (dict(batch=True, discount=-0.5), "a discount is a number of at least 0 on a batch price, got -0.5"),
    ],
)
def test_a_bad_price_is_refused_naming_the_field(fields, said):
    good = dict(
        input_usd_per_mtok=3.0,
        output_usd_per_mtok=15.0,
        cache_read_usd_per_mtok=0.3,
        cache_write_usd_per_mtok=3.75,
        source="a price page",
    )
    Price(**good)
    with pytest.raises(ValueError, match=re.escape(said)):
        Price(**{**good, **fields})
