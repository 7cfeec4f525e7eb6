"""Text that UTF-8 can carry: lone surrogates (half of an emoji, escaped in JSON as ``"\\ud83d"``) as U+FFFD.

A lone surrogate is no Unicode character: no UTF-8 file, request or terminal can hold it, and every
writer and library downstream (JSON lines, matplotlib, HTML, hashes) fails on it. Where text enters
lightemma from outside — a model's answer, a reference result file, a file name — each one becomes
U+FFFD, the replacement character, one for one; every other character is kept.
"""

from __future__ import annotations

import re
from typing import Any

_SURROGATE = re.compile("[\ud800-\udfff]")


def unicode_clean(text: str) -> str:
    """``text`` with each lone surrogate as U+FFFD (a string that encodes is returned as it is)."""
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        return _SURROGATE.sub("\ufffd", text)
    return text


def without_lone_surrogates(value: Any) -> Any:
    """``value`` (JSON data: dicts, lists, strings, numbers) with :func:`unicode_clean` applied to every string, keys too."""
    if isinstance(value, str):
        return unicode_clean(value)
    if isinstance(value, dict):
        return {without_lone_surrogates(k): without_lone_surrogates(v) for k, v in value.items()}
    if isinstance(value, list):
        return [without_lone_surrogates(v) for v in value]
    return value
