"""One small named cache type for the bridge's module-level caches of computed numbers.

A cache is an explicit, documented registry object (never a bare module dict): it holds numbers and numpy
arrays keyed by hashable identities (an object's ``session_uid``, a name and a revision), never Blender
datablocks; it keeps at most ``capacity`` entries (least recently used dropped first) and can be emptied at
any time (an entry is recomputed at its next use).
"""
from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable, Hashable
from typing import Any

__all__ = ["BoundedCache"]


class BoundedCache:
    """A named least-recently-used cache of at most ``capacity`` entries.

    Parameters
    ----------
    name : str
        What it holds (for its ``repr`` and the docs).
    capacity : int
        Entries kept (≥ 1); the least recently used is dropped first.
    """

    def __init__(self, name: str, capacity: int):
        if capacity < 1:
            raise ValueError(f"capacity must be ≥ 1, got {capacity}")
        self.name = name
        self.capacity = int(capacity)
        self._entries: OrderedDict = OrderedDict()

    def __len__(self) -> int:
        return len(self._entries)

    def __repr__(self) -> str:
        return f"BoundedCache({self.name!r}, {len(self)}/{self.capacity})"

    def clear(self) -> None:
        """Forget every entry."""
        self._entries.clear()

    def get(self, key: Hashable, valid: Callable[[Any], bool] | None = None) -> Any:
        """The entry of ``key`` (marked most recently used), or None when absent or ``valid(entry)`` is false
        (the stale entry is dropped)."""
        entry = self._entries.get(key)
        if entry is None:
            return None
        if valid is not None and not valid(entry):
            del self._entries[key]
            return None
        self._entries.move_to_end(key)
        return entry

    def put(self, key: Hashable, entry: Any) -> Any:
        """Store ``entry`` under ``key`` (dropping the least recently used beyond ``capacity``); returns it."""
        self._entries[key] = entry
        self._entries.move_to_end(key)
        while len(self._entries) > self.capacity:
            self._entries.popitem(last=False)
        return entry
