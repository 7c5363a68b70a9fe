"""Zenoh's error messages made readable: the Rust source location Zenoh appends
(``at /root/.cargo/git/checkouts/zenoh-.../lib.rs:1484.``) removed, and a config
file's parse error said as ``line L, column C: reason``, Zenoh's own words kept.
"""

from __future__ import annotations

import difflib
import json
import re

__all__ = ["config_file_problem", "without_source_location"]

_SOURCE_LOCATION = re.compile(r"\s+at\s+[^\s\]]+\.rs:\d+\.?")
# serde's error through json5: Message { msg: "...", location: Some(Location { line, column }) }
_SERDE = re.compile(
    r'JSON error: Message \{ msg: "((?:[^"\\]|\\.)*)", '
    r"location: Some\(Location \{ line: (\d+), column: (\d+) \}\) \}"
)
_SERDE_NOWHERE = re.compile(r'JSON error: Message \{ msg: "((?:[^"\\]|\\.)*)", location: None \}')
# json5's own syntax error (pest): " --> L:C", the line and a caret, "= reason"
_PEST = re.compile(r"-->\s*(\d+):(\d+)\s*\n(.*)\n\s*=\s*(.+?)\s*$", re.DOTALL)
_UNKNOWN = re.compile(r"unknown (?:field|variant) `([^`]+)`, expected (.+)")


def without_source_location(text: str) -> str:
    """``text`` without the ``at FILE.rs:LINE.`` Zenoh ends its messages (and the
    messages nested in them) with."""
    return _SOURCE_LOCATION.sub("", text.strip())


def config_file_problem(text: str) -> str:
    """What is wrong with a Zenoh config file, from the error Zenoh's loader raised."""
    text = without_source_location(text)
    if match := _SERDE.search(text):
        reason, line, column = _unescape(match[1]), match[2], match[3]
        return f"line {line}, column {column}: {_did_you_mean(reason)}"
    if match := _SERDE_NOWHERE.search(text):
        return _did_you_mean(_unescape(match[1]))
    if match := _PEST.search(text):
        line, column, snippet, reason = match[1], match[2], match[3], match[4]
        shown = [row.rstrip() for row in snippet.splitlines() if row.strip() not in ("", "|")]
        return "\n".join([f"line {line}, column {column}: {reason}", *shown])
    return text


def _unescape(quoted: str) -> str:
    try:
        value = json.loads(f'"{quoted}"')
    except ValueError:
        return quoted
    return value if isinstance(value, str) else quoted


def _did_you_mean(reason: str) -> str:
    """``reason``, an unknown field or variant followed by the closest known one."""
    match = _UNKNOWN.search(reason)
    if match is None:
        return reason
    known = re.findall(r"`([^`]+)`", match[2])
    close = difflib.get_close_matches(match[1], known, n=1, cutoff=0.6)
    if not close:
        return reason
    named = f"`{match[1]}`, expected"
    return reason.replace(named, f"`{match[1]}` (did you mean `{close[0]}`?), expected", 1)
