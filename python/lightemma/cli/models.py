"""``lightemma models``: the model registry — names, provider ids, backends, prices and their sources, reasoning."""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        "models",
        help="list the model registry: names for --model, provider ids, backends, prices, reasoning",
        description="List the registry: the name to give --model, the paper's display name, the provider id "
        "(litellm model string or Hugging Face checkpoint), the backend, the price per million tokens and where it "
        "comes from, and whether the model reasons before answering (and the output tokens added for it). Any other "
        "litellm model string, or openai/NAME with --api-base, works too.",
    )
    parser.add_argument("--format", default="md", choices=("md", "json"), help="output format (default: md)")
    parser.set_defaults(func=main)
    return parser


def rows() -> list[dict[str, Any]]:
    """One plain dict per registry entry: what ``lightemma models`` prints."""
    from lightemma.models.catalog import MODELS
    from lightemma.models.prices import batch_price, list_models

    out = []
    for entry, info in zip(list_models(), MODELS):
        price, batch = entry["price"], batch_price(info)
        out.append(
            {
                "key": entry["key"],
                "display_name": entry["display_name"],
                "provider_id": entry["model_id"],
                "backend": entry["backend"],
                "input_usd_per_mtok": price["input_usd_per_mtok"],
                "output_usd_per_mtok": price["output_usd_per_mtok"],
                "price_source": price["source"],
                "batch_input_usd_per_mtok": batch["input_usd_per_mtok"],
                "batch_output_usd_per_mtok": batch["output_usd_per_mtok"],
                "batch_price_source": batch["source"] if batch["input_usd_per_mtok"] is not None else None,
                "reasoning": entry["reasoning"],
                "reasoning_budget": entry["reasoning_budget"],
                "in_paper": entry["in_paper"],
            }
        )
    return out


def _money(value: float | None) -> str:
    return "-" if value is None else f"{value:g}"


def markdown(table: list[dict[str, Any]]) -> str:
    """The registry as a Markdown table."""
    lines = [
        "| --model | name | provider id | backend | $ / MTok in | $ / MTok out | price source | --batch $ in / out | reasoning |",
        "|---|---|---|---|---:|---:|---|---:|---|",
    ]
    for r in table:
        reasoning = f"yes (+{r['reasoning_budget']} output tokens)" if r["reasoning"] else "no"
        if not r["reasoning"] and r["provider_id"].startswith("anthropic/"):
            reasoning = "no (extended thinking not requested)"
        lines.append(
            f"| `{r['key']}` | {r['display_name']} | `{r['provider_id']}` | {r['backend']} | "
            f"{_money(r['input_usd_per_mtok'])} | {_money(r['output_usd_per_mtok'])} | {r['price_source']} | "
            f"{_money(r['batch_input_usd_per_mtok'])} / {_money(r['batch_output_usd_per_mtok'])} | {reasoning} |"
        )
    lines.append("")
    lines.append(
        "Any other litellm model string (anthropic/…, gemini/…) or openai/NAME with --api-base also works; "
        "local checkpoints run with --backend hf or vllm."
    )
    return "\n".join(lines) + "\n"


def main(args: argparse.Namespace) -> int:
    table = rows()
    if args.format == "json":
        sys.stdout.write(json.dumps(table, indent=2) + "\n")
    else:
        sys.stdout.write(markdown(table))
    return 0
