"""The one small least-recently-used cache used wherever holofit keeps recent results.

Engines keep a few lattices, solved systems and detector grids; the ADDA adapter a few runs;
the fit a few solved waves. ``functools.lru_cache`` does not fit these (the values belong to an
object, keys are built by hand, and some evictions must release related state), so they share
this class instead of each writing its own ordered-dict bookkeeping.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable, Hashable, Iterator
from typing import Generic, TypeVar

__all__ = ["LRUCache"]

K = TypeVar("K", bound=Hashable)
V = TypeVar("V")


class LRUCache(Generic[K, V]):
    """A mapping that keeps the ``maxsize`` most recently used entries.

    Parameters
    ----------
    maxsize : int
        Most entries kept (>= 1).
    on_evict : callable, optional
        Called as ``on_evict(key, value)`` for every entry pushed out by a newer one (what it
        returns is ignored).
    """

    def __init__(self, maxsize: int, on_evict: Callable[[K, V], object] | None = None) -> None:
        if maxsize < 1:
            raise ValueError(f"maxsize must be >= 1, got {maxsize}")
        self.maxsize = maxsize
        self._on_evict = on_evict
        self._data: OrderedDict[K, V] = OrderedDict()

    def get(self, key: K) -> V | None:
        """The value of ``key`` (marked as most recently used), or None."""
        value = self._data.get(key)
        if value is not None:
            self._data.move_to_end(key)
        return value

    def put(self, key: K, value: V) -> V:
        """Store ``value`` under ``key``, evicting the least recently used entries; returns it."""
        self._data[key] = value
        self._data.move_to_end(key)
        while len(self._data) > self.maxsize:
            old_key, old_value = self._data.popitem(last=False)
            if self._on_evict is not None:
                self._on_evict(old_key, old_value)
        return value

    def get_or_create(self, key: K, make: Callable[[], V]) -> V:
        """The value of ``key``, made by ``make()`` and stored if absent."""
        value = self.get(key)
        return self.put(key, make()) if value is None else value

    def items(self) -> Iterator[tuple[K, V]]:
        """Entries from least to most recently used."""
        return iter(list(self._data.items()))

    def clear(self) -> None:
        """Forget every entry (no eviction callbacks)."""
        self._data.clear()

    def __contains__(self, key: object) -> bool:
        return key in self._data

    def __len__(self) -> int:
        return len(self._data)
