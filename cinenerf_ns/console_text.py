"""User text through rich, printed as typed: never markup, never emoji codes.

Rich reads '[red]' / '[/x]' in a printed string as markup (a stray closing tag raises MarkupError, after the outputs
were written) and ':smile:' as an emoji. Queries, their resolved descriptions, file paths, label and export names, and
error messages that quote them go through ``lit`` (inside a markup string printed with ``emoji=False``) or
``error_line`` / ``Text`` (never parsed at all)."""
from __future__ import annotations

from typing import Any

from rich.markup import escape
from rich.text import Text


def lit(value: Any) -> str:
    """str(value) escaped for a rich markup string ('[red]' prints as '[red]'). escape() leaves ':smile:' codes alone:
    print the string with emoji=False (or through a Console(emoji=False))."""
    return escape(str(value))


def error_line(prog: str, message: Any) -> Text:
    """'prog: message' with the program name in bold red and the message as plain text; print it with soft_wrap=True
    so that the message stays one line, as written."""
    return Text.assemble((f"{prog}:", "bold red"), " ", str(message))
