"""The "did you mean" of every unknown name a user types (a configuration key, a bus
interface, a command-line verb): one rule for what counts as close."""

from __future__ import annotations

import difflib
from collections.abc import Iterable

CUTOFF = 0.6
"""The least similarity (difflib's ratio) of a suggestion to the typed name."""


def closest(word: str, choices: Iterable[str]) -> str | None:
    """The choice closest to `word` if it is close enough (CUTOFF), else None. Raises nothing."""
    close = difflib.get_close_matches(word, sorted(choices), n=1, cutoff=CUTOFF)
    return close[0] if close else None
