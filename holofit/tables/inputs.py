"""Reading the tables that the DDA stages start from (the prefit's, the library's) and checking
that they belong to the crops and the particle at hand.

Every table written by holofit records in its sidecar the fingerprint of the crop table it was
made from (``crops``); a stage refuses a table made from other crops, naming both files, since
frame numbers alone would silently pair the wrong holograms with the wrong starts.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import pandas as pd

from holofit.io.tables import sidecar_path
from holofit.tables.cropset import CropSet, CropSetError

__all__ = ["StageInputError", "read_stage_table", "usable_start"]


class StageInputError(CropSetError):
    """A prefit or library table that is missing, unreadable, or made for other crops."""


def read_stage_table(path: str | Path, crops: CropSet, what: str) -> tuple[pd.DataFrame,
                                                                        dict[str, Any]]:
    """Read a stage's table and sidecar, checking it was made from ``crops``.

    Parameters
    ----------
    path : str or Path
        The table, or the folder holding it as ``<what>.csv``.
    crops : CropSet
        The crops being fitted.
    what : str
        ``"prefit"`` or ``"library"`` (also the file's stem when ``path`` is a folder).

    Returns
    -------
    table : pandas.DataFrame
        Indexed by ``(particle, frame)`` (a table of one track without the ``particle``
        column: the crops' track).
    meta : dict
        The sidecar.

    Raises
    ------
    StageInputError
        Missing or unreadable table, repeated frames, or a table made from other crops.
    """
    path = Path(path)
    if path.is_dir():
        path = path / f"{what}.csv"
    if not path.is_file():
        raise StageInputError(f"{path}: no {what} table (run `holofit {what}` first?)")
    try:
        table = pd.read_csv(path)
    except (ValueError, pd.errors.ParserError) as exc:
        raise StageInputError(f"{path}: not a readable {what} table ({exc})") from None
    if "frame" not in table.columns or "status" not in table.columns:
        raise StageInputError(f"{path}: not a {what} table (no frame/status columns)")
    multi = bool(getattr(crops, "multi", False))
    keys = ["particle", "frame"]
    if "particle" not in table.columns:
        if multi:
            raise StageInputError(f"{path}: no particle column, but {crops.table_path} holds "
                                  "several tracks: rerun `holofit " + what + "` on these crops")
        table.insert(0, "particle", crops.particles[0] if crops.particles else 0)
    if table.duplicated(keys).any():
        raise StageInputError(f"{path}: repeated frame numbers" if not multi
                              else f"{path}: repeated (particle, frame) rows")
    side = sidecar_path(path)
    meta: dict[str, Any] = {}
    if side.is_file():
        try:
            meta = json.loads(side.read_text())
        except ValueError as exc:
            raise StageInputError(f"{side}: not valid JSON ({exc})") from None
    made_from = meta.get("crops")
    if isinstance(made_from, dict):
        now = crops.fingerprint()
        if made_from.get("crops_csv_sha256") != now["crops_csv_sha256"]:
            raise StageInputError(
                f"{path} was made from other crops than {crops.table_path} (the crop table's "
                f"checksum differs): rerun `holofit {what}` on these crops"
            )
    return table.set_index(keys, drop=False).rename_axis([None, None]), meta


def usable_start(row: dict[str, Any] | None) -> str:
    """Why a prefit row cannot start a DDA fit ('' if it can): it must hold a finite position
    and alpha (any converged status will do: a sphere model rarely fits a rod well)."""
    if row is None:
        return "no row for this frame"
    bad = [c for c in ("x_um", "y_um", "z_um", "alpha")
           if not isinstance(row.get(c), int | float) or not math.isfinite(float(row[c]))]
    if bad:
        status = row.get("status", "?")
        return f"its {', '.join(bad)} missing (status {status})"
    return ""
