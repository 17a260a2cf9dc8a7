"""The item key of a batch: which row of a stage table an item is.

A batch runs one *item function* on many items; each item is named by a key, and the table
holds one row per key, with the key in its *key columns*. The crop stage's search runs per
frame (:data:`FRAME_KEY`: a key is the frame number); every stage after it is keyed by
``("particle", "frame")`` (:data:`holofit.tables.cropset.PARTICLE_KEY`: a key is a tuple of
the same length as the key columns). The batch runner, its journal and the stage skeleton
(:mod:`holofit.batch.stage`) treat a key only through the functions here, so one runner
serves every key.

A *multi-row item* (a chunk of a track: several frames fitted in one go) returns several rows,
each with its own key; one of them has the item's key (:func:`item_rows` checks it and puts it
last). The batch counts items by their own key: an item is done when its row is in the
journal or the table, and since that row is written after the item's other rows, the others
are then there too. Resuming therefore never redoes a finished multi-row item.
"""

from __future__ import annotations

import numbers
from collections.abc import Hashable, Iterable, Mapping, Sequence
from typing import Any

__all__ = [
    "FRAME_KEY",
    "Key",
    "check_key_columns",
    "item_rows",
    "key_of_row",
    "key_row",
    "normal_key",
    "sorted_keys",
]

#: an item's key: a frame number, or a tuple with one value per key column
Key = Hashable

#: the key columns of a per-frame stage table
FRAME_KEY: tuple[str, ...] = ("frame",)


def _plain(value: Any) -> Any:
    """A key value as a plain Python value (numpy and float integers -> int)."""
    if isinstance(value, bool):
        return value
    if isinstance(value, numbers.Integral):
        return int(value)
    if isinstance(value, numbers.Real) and float(value).is_integer():
        return int(float(value))  # a float-typed whole number (e.g. a frame read back as 3.0)
    return value


def check_key_columns(key_columns: Sequence[str]) -> tuple[str, ...]:
    """The key columns as a non-empty tuple of distinct names; ValueError otherwise."""
    cols = tuple(str(c) for c in key_columns)
    if not cols or len(set(cols)) != len(cols):
        raise ValueError(f"key_columns must be distinct names, at least one, got {cols}")
    return cols


def normal_key(key: Any, key_columns: Sequence[str]) -> Key:
    """``key`` in its one form: a plain value for one key column, a tuple for several.

    Raises
    ------
    ValueError
        A tuple key whose length is not the number of key columns.
    """
    if len(key_columns) == 1:
        if isinstance(key, tuple):
            if len(key) != 1:
                raise ValueError(f"key {key!r} for key column {key_columns[0]!r}")
            key = key[0]
        return _plain(key)
    if not isinstance(key, tuple) or len(key) != len(key_columns):
        raise ValueError(f"key {key!r} does not match key columns {tuple(key_columns)}")
    return tuple(_plain(v) for v in key)


def sorted_keys(keys: Iterable[Key]) -> list[Key]:
    """``keys`` in ascending order, as ``sorted`` gives them.

    The keys of one table are all plain values or all tuples of plain values
    (:func:`normal_key`), so they compare; :data:`Key` (any hashable) cannot say so.
    """
    ordered: list[Any] = list(keys)
    ordered.sort()
    return ordered


def key_row(key: Key, key_columns: Sequence[str]) -> dict[str, Any]:
    """The key columns' values of the row of ``key``."""
    values = (key,) if len(key_columns) == 1 else tuple(key)  # type: ignore[arg-type]
    return {c: _plain(v) for c, v in zip(key_columns, values, strict=True)}


def key_of_row(row: Mapping[str, Any], key_columns: Sequence[str]) -> Key:
    """The key of a table row (from its key columns)."""
    if len(key_columns) == 1:
        return _plain(row[key_columns[0]])
    return tuple(_plain(row[c]) for c in key_columns)


def item_rows(rows: Sequence[Mapping[str, Any]], key: Key, key_columns: Sequence[str]
              ) -> list[dict[str, Any]]:
    """The rows of a multi-row item, the one whose key is the item's own ``key`` last.

    Raises
    ------
    ValueError
        No row has the item's key, a row lacks a key column, or two rows share a key.
    """
    own = normal_key(key, key_columns)
    out: list[dict[str, Any]] = []
    last: dict[str, Any] | None = None
    seen: set[Key] = set()
    for row in rows:
        missing = [c for c in key_columns if c not in row]
        if missing:
            raise ValueError(f"item {own!r}: a row without key column(s) {missing}")
        k = key_of_row(row, key_columns)
        if k in seen:
            raise ValueError(f"item {own!r}: two rows with key {k!r}")
        seen.add(k)
        if k == own:
            last = dict(row)
        else:
            out.append(dict(row))
    if last is None:
        raise ValueError(f"item {own!r}: none of its {len(out)} rows has the item's key")
    return [*out, last]
