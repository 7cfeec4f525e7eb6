"""Token rules for estimates: each provider's published image-token rule, and a frame's typical output tokens.

:func:`image_rule` gives each model's published image-token rule (:data:`IMAGE_RULES`, each with its source and the
date it was read; None where no rule is published), which ``--estimate`` and ``--max-cost`` use;
:func:`typical_output_tokens` the output tokens per frame, from the paper's Table I (:mod:`lightemma.models.paper`).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

from lightemma.errors import InputError
from lightemma.models.catalog import ModelInfo, _norm
from lightemma.models.paper import paper_efficiency_rows

# --- image tokens, for estimates ------------------------------------------------------------------------
# Each rule below carries where it is published and the date it was read. Where the provider's own page could not be
# read as stored text, the copy that quotes it is named as well. A model whose rule is not published, or whose
# published readings disagree, has none (:func:`image_rule` returns None): its estimate says "unknown" for images and
# ``--max-cost`` counts its calls at :func:`lightemma.pipeline.estimate.frame_cost_upper_bound`, never at a guess.
IMAGE_RULES_READ = "2026-12-03"
OPENAI_VISION_DOC = "platform.openai.com/docs/guides/images-vision#calculating-costs"
ANTHROPIC_VISION_DOC = "docs.anthropic.com/en/docs/build-with-claude/vision#calculate-image-costs"
GEMINI_TOKENS_DOC = "ai.google.dev/gemini-api/docs/tokens (images)"
GEMINI_MEDIA_RESOLUTION_DOC = "ai.google.dev/gemini-api/docs/media-resolution#token-counts"


@dataclass(frozen=True)
class ImageRule:
    """A provider's published rule for the input tokens one image costs, for the models it names.

    ``kind``:

    * ``tile`` (OpenAI, ``detail: high``): fit in 2048 × 2048, scale the short side down to 768, then
      ``base + tile × (512-px tiles)``;
    * ``patch`` (OpenAI's newer minis): 32-px patches, at most 1536 (a larger image is scaled down to fit,
      each side to a whole number of patches), times ``multiplier``, rounded up;
    * ``anthropic``: scale down until the long side is at most 1568 px and the area at most 1092 × 1092 px
      (the documented ~1,600-token maximum), then ``ceil(width × height / 750)``;
    * ``gemini-tile`` (Gemini 2.x): 258 for an image within 384 × 384, else 258 per 768 × 768 tile;
    * ``per-image``: ``tokens`` per image whatever its size (``exact`` False: a documented maximum).

    ``source`` is where the rule is published and when it was read; ``exact`` is False where the rule gives a
    maximum rather than the count; ``provider`` is whose rule it is (``openai``, ``anthropic``, ``gemini``), what the
    estimate line names (``anthropic rule``) whichever server the model is reached through.
    """

    name: str
    kind: str
    source: str
    base: int = 0
    tile: int = 0
    multiplier: float = 1.0
    tokens_per_image: int = 0
    exact: bool = True
    provider: str = "openai"  # whose rule it is (the estimate line names it: 'anthropic rule')

    def tokens(self, width: int, height: int) -> int:
        """Input tokens of one ``width`` × ``height`` image (pixels) under this rule; ValueError for a size below 1."""
        if width < 1 or height < 1:
            raise InputError(f"an image needs a positive size, got {width} × {height}")
        if self.kind == "tile":
            scale = min(1.0, 2048 / max(width, height))
            w, h = width * scale, height * scale
            scale = min(1.0, 768 / min(w, h))
            w, h = w * scale, h * scale
            return self.base + self.tile * math.ceil(w / 512) * math.ceil(h / 512)
        if self.kind == "patch":
            return math.ceil(_patches(width, height) * self.multiplier - 1e-9)
        if self.kind == "anthropic":
            scale = min(
                1.0, ANTHROPIC_MAX_SIDE / max(width, height), math.sqrt(ANTHROPIC_MAX_PIXELS / (width * height))
            )
            return math.ceil(round(width * scale) * round(height * scale) / 750)
        if self.kind == "gemini-tile":
            if width <= 384 and height <= 384:
                return 258
            return 258 * math.ceil(width / 768) * math.ceil(height / 768)
        if self.kind == "per-image":
            return self.tokens_per_image
        raise ValueError(f"unknown image rule kind {self.kind!r}")

    def describe(self) -> str:
        """One line: the rule, ``at most`` where it is a maximum, and its source."""
        return f"{self.name} ({self.source})"


#: Anthropic: the long side at most 1568 px; the area at most that of the 1:1 (1092 × 1092) and 9:16 (819 × 1456)
#: rows of the documented table of largest unresized sizes (~1,600 tokens)
ANTHROPIC_MAX_SIDE, ANTHROPIC_MAX_PIXELS = 1568, 1092 * 1092
PATCH_SIZE, PATCH_LIMIT = 32, 1536


def _patches(width: int, height: int) -> int:
    """32-px patches of an image after OpenAI's downscaling to at most :data:`PATCH_LIMIT` patches (the documented
    steps: shrink by √(32² × 1536 / (w × h)), then further so that each side is a whole number of patches)."""
    raw = math.ceil(width / PATCH_SIZE) * math.ceil(height / PATCH_SIZE)
    if raw <= PATCH_LIMIT:
        return raw
    r = math.sqrt(PATCH_SIZE**2 * PATCH_LIMIT / (width * height))
    w_p, h_p = width * r / PATCH_SIZE, height * r / PATCH_SIZE
    r *= min(math.floor(w_p) / w_p, math.floor(h_p) / h_p)
    return min(PATCH_LIMIT, math.ceil(width * r / PATCH_SIZE - 1e-9) * math.ceil(height * r / PATCH_SIZE - 1e-9))


def _openai_tile(name: str, base: int, tile: int, quoted: str) -> ImageRule:
    return ImageRule(
        name=f"OpenAI tiles (detail high): {base} + {tile} per 512-px tile",
        kind="tile",
        base=base,
        tile=tile,
        source=f"{OPENAI_VISION_DOC}, {name} row; as quoted by {quoted} (stored copies), read {IMAGE_RULES_READ}",
    )


def _openai_patch(name: str, multiplier: float) -> ImageRule:
    return ImageRule(
        name=f"OpenAI 32-px patches (at most {PATCH_LIMIT}) × {multiplier:g}",
        kind="patch",
        multiplier=multiplier,
        source=f"{OPENAI_VISION_DOC}, patch rule, {name} multiplier; as quoted by "
        f"github.com/xn1cklas/tokenlens/issues/7 and community.openai.com/t/1230130 (stored copies), "
        f"read {IMAGE_RULES_READ}",
    )


_DATE = r"(-\d{4}-\d{2}-\d{2})?"
_GPT4O_QUOTES = "v2ex.com/t/1044688 (the page's text with its 765- and 1105-token examples) and a64.in's calculator"
_GPT4O_MINI_QUOTES = "github.com/epam/ai-dial-adapter-openai/issues/165 and github.com/autogenhub/autogen/pull/57"
_CLAUDE = (
    r"claude-(3-haiku|3-sonnet|3-opus|3-5-sonnet|3-5-haiku|3-7-sonnet|sonnet-4|opus-4|opus-4-1|sonnet-4-5|"
    r"haiku-4-5|opus-4-5|sonnet-4-6|opus-4-6)(-\d{8}|-latest)?"
)
#: (pattern over the model id without its provider prefix, rule), first match wins. Left out on purpose, with why:
#: gpt-4.1 (the docs' patch rule at × 1 and the billed tile rule disagree: community.openai.com/t/1230130);
#: gpt-5-mini and gpt-5-nano (the docs' × 1.62 / × 2.46 and OpenAI's pricing calculator's × 1.2 / × 1.5 disagree:
#: community.openai.com/t/1344040); gpt-5, gpt-5.2, the o-series but o4-mini and gpt-4.5 (no base/tile figures for
#: them in any copy read); Claude models after 4.6 (a higher-resolution tier).
IMAGE_RULES: tuple[tuple[str, ImageRule], ...] = (
    (rf"gpt-4o-mini{_DATE}", _openai_tile("4o-mini", 2833, 5667, _GPT4O_MINI_QUOTES)),
    (rf"gpt-4o{_DATE}", _openai_tile("4o", 85, 170, _GPT4O_QUOTES)),
    (rf"gpt-4\.1-mini{_DATE}", _openai_patch("gpt-4.1-mini", 1.62)),
    (rf"gpt-4\.1-nano{_DATE}", _openai_patch("gpt-4.1-nano", 2.46)),
    (rf"o4-mini{_DATE}", _openai_patch("o4-mini", 1.72)),
    (
        _CLAUDE,
        ImageRule(
            name=f"Anthropic: long side ≤ {ANTHROPIC_MAX_SIDE} px, area ≤ 1092 × 1092 px, width × height / 750",
            kind="anthropic",
            provider="anthropic",
            source=f"{ANTHROPIC_VISION_DOC} (stored copies of docs.anthropic.com/en/docs/vision "
            f"and platform.claude.com/docs/*/build-with-claude/vision), read {IMAGE_RULES_READ}",
        ),
    ),
    (
        r"gemini-2\.(0|5)-[a-z0-9.-]+",
        ImageRule(
            name="Gemini 2.x: 258 within 384 × 384 px, else 258 per 768 × 768 tile",
            kind="gemini-tile",
            provider="gemini",
            source=f"{GEMINI_TOKENS_DOC}; as quoted by geminibyexample.com/027-calculate-input-tokens (stored "
            f"copy), read {IMAGE_RULES_READ}",
        ),
    ),
    (
        r"gemini-3(\.\d+)?-[a-z0-9.-]+",
        ImageRule(
            name="Gemini 3: at most 1120 per image (media resolution high, the default for images)",
            kind="per-image",
            tokens_per_image=1120,
            exact=False,
            provider="gemini",
            source=f"{GEMINI_MEDIA_RESOLUTION_DOC}; as quoted by fastgptplus.com/en/posts/gemini-3-pro-media-"
            f"resolution-parameter (stored copy), read {IMAGE_RULES_READ}",
        ),
    ),
)
#: provider prefixes of litellm model strings whose bare model name the rules above are about
_RULE_PREFIXES = ("openai/", "anthropic/", "gemini/", "vertex_ai/")


def image_rule(model: ModelInfo | str) -> ImageRule | None:
    """The published image-token rule of ``model`` (a registry entry or a litellm model string), or None when no rule
    is published for it or its published readings disagree (:data:`IMAGE_RULES`, which says which and why)."""
    model_id = model.model_id if isinstance(model, ModelInfo) else str(model)
    name = _norm(model_id)
    for prefix in _RULE_PREFIXES:
        if name.startswith(prefix):
            name = name[len(prefix) :]
            break
    if "/" in name:  # another provider's route (openrouter/…, azure/…): its billing is not the rule's
        return None
    for pattern, rule in IMAGE_RULES:
        if re.fullmatch(pattern, name):
            return rule
    return None


#: each provider's default rule, for :func:`image_tokens` by provider (the estimate uses :func:`image_rule` per model)
def _named_rule(model: str) -> ImageRule:
    rule = image_rule(model)
    if rule is None:  # pragma: no cover - the table names these models
        raise LookupError(f"no image rule for {model}")
    return rule


_PROVIDER_RULES = {
    provider: _named_rule(model)
    for provider, model in (("openai", "gpt-4o"), ("anthropic", "claude-3-7-sonnet"), ("gemini", "gemini-2.0-flash"))
}
#: where each provider's image-token rules are published (shown by ``--estimate``)
IMAGE_TOKEN_RULES = {
    "openai": f"{OPENAI_VISION_DOC} (detail high: fit in 2048 × 2048, short side to 768, base + tile per 512-px tile, "
    "per model; or 32-px patches × a per-model multiplier)",
    "anthropic": f"{ANTHROPIC_VISION_DOC} (long side to at most 1568 px, area to at most ~1,600 tokens, tokens = "
    "width × height / 750)",
    "gemini": f"{GEMINI_TOKENS_DOC} (258 tokens for an image within 384 × 384, else 258 per 768 × 768 tile; Gemini 3: "
    f"{GEMINI_MEDIA_RESOLUTION_DOC})",
}


def image_tokens(width: int, height: int, provider: str) -> int:
    """Input tokens one ``width`` × ``height`` image costs under ``provider``'s base rule (``openai``: gpt-4o's tiles,
    ``anthropic``, ``gemini`` / ``vertex_ai``: Gemini 2.x tiles); any other provider is counted as ``openai``.

    A model's own rule can differ (gpt-4o-mini's tiles cost 33 × gpt-4o's): :func:`image_rule` gives it, and the
    estimate uses that. ValueError for a size below 1.
    """
    rule = _PROVIDER_RULES.get("gemini" if provider == "vertex_ai" else provider, _PROVIDER_RULES["openai"])
    return rule.tokens(width, height)


#: output tokens per frame (three stages, first attempt) for a model the paper did not run
DEFAULT_OUTPUT_TOKENS = 400


def typical_output_tokens(info: ModelInfo) -> tuple[int, str]:
    """Output tokens a frame typically takes (all three stages) and where the figure comes from:
    the paper's Table I for its models, else :data:`DEFAULT_OUTPUT_TOKENS` (about the paper's median)."""
    for row in paper_efficiency_rows():
        if row["model"] == info.display_name and row.get("output_tokens"):
            return int(row["output_tokens"]), "the paper's Table I"
    return DEFAULT_OUTPUT_TOKENS, "lightemma's default (about the paper's median)"
