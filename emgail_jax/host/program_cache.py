"""Compiled programs kept across the runners of one process.

Runners whose programs differ only in their data (the sweep's driver radii, a test session's
tiny runs) share one compiled set: a second run neither traces nor compiles again. The cache
keeps the most recently used sets and drops the others, so that a long session does not hold
every program it compiled.
"""

from __future__ import annotations

import collections
from collections.abc import Callable, Hashable
from typing import Any

# Enough for a sweep's runs of one algorithm (one chunk length and a remainder each).
SHARED_PROGRAMS = 4


class ProgramCache:
    """A least-recently-used map of program sets, at most ``size`` of them."""

    def __init__(self, size: int = SHARED_PROGRAMS):
        self.size = size
        self._entries: collections.OrderedDict[Hashable, Any] = collections.OrderedDict()

    def get(self, key: Hashable, build: Callable[[], Any]) -> Any:
        """The set kept under ``key``, built on first use; the least recently used beyond
        ``size`` are dropped."""
        if key not in self._entries:
            self._entries[key] = build()
        self._entries.move_to_end(key)
        while len(self._entries) > self.size:
            self._entries.popitem(last=False)
        return self._entries[key]

    def keys(self) -> list[Hashable]:
        """The keys kept, least recently used first."""
        return list(self._entries)

    def clear(self) -> None:
        self._entries.clear()

    def __len__(self) -> int:
        return len(self._entries)


# The process's cache, which every runner given a program key uses.
SHARED = ProgramCache()
