"""Tables (CSV) with a sidecar JSON of units and provenance, written atomically."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from holofit.io.atomic import atomic_path, atomic_write_text

__all__ = ["TEXT_COLUMNS", "read_table", "sidecar_path", "write_json", "write_table"]


def sidecar_path(path: str | Path) -> Path:
    """``results.csv`` -> ``results.csv.json``."""
    path = Path(path)
    return path.with_name(path.name + ".json")


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _jsonable(obj.tolist())
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.floating):
        return float(obj)
    if isinstance(obj, complex | np.complexfloating):
        return [float(obj.real), float(obj.imag)]
    if isinstance(obj, Path):
        return str(obj)
    return obj


def write_json(path: str | Path, document: dict[str, Any]) -> None:
    """Write a JSON document atomically (numpy scalars, arrays and complex are converted)."""
    atomic_write_text(path, json.dumps(_jsonable(document), indent=2, allow_nan=True) + "\n")


def write_table(path: str | Path, table: pd.DataFrame, meta: dict[str, Any] | None = None) -> Path:
    """Write ``table`` as CSV and ``meta`` as its sidecar JSON, both atomically.

    The sidecar is written first, so a complete CSV always has its sidecar.

    Returns
    -------
    Path
        The CSV path.
    """
    path = Path(path)
    if meta is not None:
        write_json(sidecar_path(path), meta)
    with atomic_path(path) as tmp:
        table.to_csv(tmp, index=False, float_format="%.10g")
    return path


#: columns of text in every stage's tables
TEXT_COLUMNS = ("status", "message")


def read_table(path: str | Path) -> pd.DataFrame:
    """Read a CSV table written by :func:`write_table` (or any CSV with a header).

    The text columns every stage writes (:data:`TEXT_COLUMNS`) are read as text, empty cells
    as ``""``: a column whose every cell is empty would otherwise be read as floats (NaN),
    into which no message can be written later.
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: table not found")
    table = pd.read_csv(path)
    for name in TEXT_COLUMNS:
        if name in table.columns and pd.api.types.is_numeric_dtype(table[name]):
            table[name] = table[name].astype(object).where(table[name].notna(), "")
    return table
