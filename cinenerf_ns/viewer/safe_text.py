"""Text from users made inert for viser's markdown, and the paths clients are shown.

viser 1.1.1 renders a markdown widget's content with raw HTML enabled (client ``Markdown.tsx``: remark-gfm, then
``rehypeRawDom`` with no sanitising), so any user text put into markdown could run script (``<iframe srcdoc>``),
restyle every page (``<style>``) or make every browser fetch a URL (``![](http://...)``). Every user string the panel
shows goes through :func:`md_escape`: HTML's special characters become entities (shown, never parsed as tags) and
every other ASCII punctuation character is backslash-escaped (CommonMark: an escaped character is literal text), so
no link, image, emphasis, heading, table or autolink can start from user text. No viser import.
"""
from __future__ import annotations

import os
import re
import string
from pathlib import Path
from typing import Optional, Union

from cinenerf_ns.planner.errors import InvalidInputError

MAX_TEXT_CHARS = 500
"""Longest text a client may put in a box (go-to, look-at, export name); longer is refused, never truncated."""

_ENTITIES = {"&": "&amp;", "<": "&lt;", ">": "&gt;"}
_ESCAPED = {c: "\\" + c for c in string.punctuation if c not in _ENTITIES}
_ESCAPED.update(_ENTITIES)
_BREAKS = re.compile(r"[\x00-\x1f\x7f\u2028\u2029\u0085]+")  # control characters and line/paragraph separators


def md_escape(text: object) -> str:
    """``text`` as markdown that renders as exactly that text on one line: no HTML, no markdown syntax.

    Control characters and line breaks become one space (a break would let user text start a block: a heading, a
    fence, an indented code block); ``&<>`` become entities; the other ASCII punctuation is backslash-escaped."""
    flat = _BREAKS.sub(" ", str(text))
    return "".join(_ESCAPED.get(c, c) for c in flat)


def md_code_block(text: str) -> str:
    """``text`` in a fenced code block: literal, whatever it contains (the fence is longer than any run of backticks
    in it)."""
    longest = max((len(m) for m in re.findall(r"`+", text)), default=0)
    fence = "`" * max(3, longest + 1)
    return f"{fence}\n{text}\n{fence}"


def client_path(path: Union[str, Path], base: Optional[Path] = None) -> str:
    """How a file is named to a browser: relative to ``base`` (or the working directory) when it lies under it, else
    its name alone. A client never learns the server's absolute paths."""
    p = Path(path)
    for root in ([Path(base)] if base is not None else []) + [Path(os.getcwd())]:
        try:
            return str(p.absolute().relative_to(root.absolute()))
        except ValueError:
            continue
    return p.name


def check_text(value: object, what: str, limit: int = MAX_TEXT_CHARS) -> str:
    """A text box's value as the server accepts it: a string of at most ``limit`` characters. Raises a
    message for users (``InvalidInputError``)."""
    if not isinstance(value, str):
        raise InvalidInputError(f"'{what}' must be text (got {type(value).__name__})")
    if len(value) > limit:
        raise InvalidInputError(f"'{what}' is {len(value)} characters long; at most {limit} are accepted")
    return value
