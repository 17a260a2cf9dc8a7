"""Per-worker set-up owned by the stage skeleton: what a frame function makes once per worker
process and reuses for every item of the batch.

A frame function runs in a worker process (or in the driver, without workers) and is called
once per item with the same picklable config. What is costly to make from that config (an
engine with its caches, a solved orientation library, an open movie with its normaliser) is
made on the first item and kept for the next ones::

    def detect_frame(config, frame, payload):
        movie, normalizer = worker_resource("crop detection", config.key,
                                            lambda: open_state(config), size=1,
                                            close=lambda state: state[0].close())
        ...

Resources are kept per *kind* in a least-recently-used cache (:class:`holofit.cache.LRUCache`)
of ``size`` entries, keyed by what identifies the config (a fingerprint), so two batches with
other settings in the same worker (a Dask worker lives across batches) do not share one; the
oldest is closed (``close``) when a newer one pushes it out. The caches are process-local: a
process forked from one that holds resources starts with none (open files and engines do not
survive a fork). A driver that ran a batch in-process releases what it no longer needs with
:func:`release_worker_resources`.

No frame function keeps module-global state of its own: the skeleton owns it here.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Hashable
from typing import Any, TypeVar

from holofit.cache import LRUCache

__all__ = ["release_worker_resources", "worker_resource", "worker_resource_kinds"]

T = TypeVar("T")


class _Kind:
    """One kind of resource in this process: its cache, how an entry is closed, and how many
    times each key's resource was made (1 when every item reused the first)."""

    def __init__(self, size: int, close: Callable[[Any], Any] | None) -> None:
        self.close = close
        self.made: dict[Hashable, int] = {}
        self.cache: LRUCache[Hashable, Any] = LRUCache(max(int(size), 1),
                                                       on_evict=self.evicted)

    def evicted(self, key: Hashable, value: Any) -> None:
        """Close a resource pushed out (or released)."""
        if self.close is not None:
            self.close(value)


#: kind -> resources of this process (emptied in a forked child: see :func:`_kinds`)
_KINDS: dict[str, _Kind] = {}
_OWNER = [os.getpid()]


def _kinds() -> dict[str, _Kind]:
    """This process's resources; a forked child drops its parent's without closing them
    (they belong to the parent)."""
    if _OWNER[0] != os.getpid():
        _KINDS.clear()
        _OWNER[0] = os.getpid()
    return _KINDS


def worker_resource(kind: str, key: Hashable, make: Callable[[], T], size: int = 2,
                    close: Callable[[T], Any] | None = None) -> T:
    """The resource ``kind`` of ``key`` in this process: made by ``make()`` on first use, then
    reused by every item of the batch (and of later batches in the same process).

    Parameters
    ----------
    kind : str
        What the resource is (``"fit engine"``, ``"library"``, ``"crop detection"``): each kind
        has its own cache, so one stage's resources never push out another's.
    key : hashable
        What identifies the config the resource is made from (its fingerprint, or canonical
        JSON of the parts that matter): items with the same key share the resource.
    make : callable
        ``make()`` builds the resource (not None). Called in the process that runs the item.
    size : int
        Most resources of this kind kept (the least recently used goes first): a pass's
        engines and its seeding engine are two.
    close : callable, optional
        ``close(resource)`` when it is pushed out or released (an open movie's ``close``).
        The first call of a kind sets it.

    Returns
    -------
    object
        The resource.
    """
    kinds = _kinds()
    entry = kinds.get(kind)
    if entry is None:
        entry = kinds[kind] = _Kind(size, close)
    elif entry.cache.maxsize != size:
        entry.cache.maxsize = max(int(size), 1)
    value = entry.cache.get(key)
    if value is None:
        value = make()
        if value is None:
            raise ValueError(f"worker_resource({kind!r}): make() returned None")
        entry.made[key] = entry.made.get(key, 0) + 1
        entry.cache.put(key, value)
    return value


def release_worker_resources(kind: str | None = None) -> None:
    """Close and forget this process's resources of ``kind`` (every kind without one).

    A driver that ran a batch in-process calls it when the batch is over, so that the files a
    frame function opened are not held open after the stage."""
    kinds = _kinds()
    for name in [kind] if kind is not None else list(kinds):
        entry = kinds.pop(name, None)
        if entry is None:
            continue
        for key, value in entry.cache.items():
            entry.evicted(key, value)
        entry.cache.clear()


def worker_resource_kinds() -> dict[str, dict[Hashable, int]]:
    """The kinds this process holds and, per key, how many times its resource was made (1 when
    every item reused the first one)."""
    return {name: dict(entry.made) for name, entry in _kinds().items()}
