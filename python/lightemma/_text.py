"""Text that UTF-8 can carry: lone surrogates (half of an emoji, escaped in JSON as ``"\\ud83d"``) as U+FFFD.

A lone surrogate is no Unicode character: no UTF-8 file, request or terminal can hold it, and every
writer and library downstream (JSON lines, matplotlib, HTML, hashes) fails on it. Where text enters
lightemma from outside — a model's answer, a reference result file, a file name — each one becomes
U+FFFD, the replacement character, one for one; every other character is kept.
"""

from __future__ import annotations

import os
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


# what a terminal or a table row must never receive raw: C0 and C1 controls and DEL (a newline forges a line, ESC
# starts a terminal sequence), the Unicode line and paragraph separators, the bidirectional overrides and isolates
# (text shown in another order than it is stored), and lone surrogates (a file name's bytes that are not UTF-8)
_UNPRINTABLE = re.compile("[\x00-\x1f\x7f-\x9f\u200e\u200f\u2028\u2029\u202a-\u202e\u2066-\u2069\ud800-\udfff]")
_NAMED_ESCAPES = {"\n": "\\n", "\r": "\\r", "\t": "\\t"}


def _escape(match: re.Match[str]) -> str:
    ch = match.group()
    if ch in _NAMED_ESCAPES:
        return _NAMED_ESCAPES[ch]
    code = ord(ch)
    if 0xDC80 <= code <= 0xDCFF:  # a byte that is not UTF-8, as os.fsdecode carries it (surrogateescape): that byte
        return f"\\x{code - 0xDC00:02x}"
    return f"\\x{code:02x}" if code <= 0xFF else f"\\u{code:04x}"


def printable(value: Any) -> str:
    """``value`` (text, a path, anything ``str`` takes) as one line that is safe to print or to put in a table cell.

    Every control character becomes a visible escape (a newline ``\\n``, ESC ``\\x1b``, DEL ``\\x7f``, U+2028
    ``\\u2028``), and so does each byte of a file name that is not UTF-8 (``\\xff``); every other character is
    kept, so an ordinary name prints as it is. Used for every name from outside (file, folder, model, scene, run)
    that a message or a table row shows: no name can split a line, forge one, or send escapes to a terminal.
    """
    text = os.fspath(value) if isinstance(value, os.PathLike) else value
    if isinstance(text, bytes):
        text = os.fsdecode(text)
    if not isinstance(text, str):
        text = str(text)
    return _UNPRINTABLE.sub(_escape, text)
