"""Overlapping (particle, frame) rows refitted with the neighbour's field, as a batch.

Where two tracks' holograms overlap (the crop table's ``overlap``), each track's first fit
is pulled off by the other's rings. Each such row whose neighbour track has a fitted row at
that frame (a finite placement, whatever its status: two overlapping first fits are both
pulled off and usually ``poor_fit``) is fitted again, warm from its own row, with the
neighbour's recorded field on the crop's pixels (:func:`neighbour_field`: its fitted
position, orientation, alpha and static parameters, through the same engine) added to the
model's field before the intensity (:mod:`holofit.holomodel.forward`, ``extra_field``).

The refits are the items of one batch of the stage skeleton (:mod:`holofit.batch.stage`)
keyed by ``(particle, frame)``, one table per pass (``overlaps/initial.csv`` and
``overlaps/fit.csv`` in the fit's folder): parallel, journalled, resumable; its fingerprint
holds both rows of every item, so new first fits start the batch afresh. The same round
serves both passes: the final pass's rows (each track's settled statics) and the initial
pass's (statics free, each row's own).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from holofit.batch.options import BatchSettings, BatchSummary
from holofit.batch.stage import StageTable, fingerprint, run_stage
from holofit.fit.problem import FrameProblem, state_of
from holofit.fit.task import PassConfig, item_theory, pass_columns
from holofit.fit.warm import fit_frame_warm
from holofit.holomodel.forward import HologramModel
from holofit.holomodel.parameters import APERTURE, ParameterSpace
from holofit.holomodel.pixels import select_pixels
from holofit.holomodel.result import result_row
from holofit.io.tables import read_table
from holofit.optics import Optics
from holofit.particles import ParticleModel
from holofit.provenance import sidecar
from holofit.scattering.theory import ScatteringEngine
from holofit.status import ERROR, OK, OVERLAP, SKIPPED
from holofit.tables.cropset import PARTICLE_KEY, CropSet

__all__ = ["Neighbours", "OverlapPayload", "mark_overlap", "neighbour_field", "overlap_rows",
           "refit_overlap_task", "refit_overlaps"]


def neighbour_field(theory: ScatteringEngine, model: ParticleModel, optics: Optics,
                    values: dict[str, float], crop_shape: tuple[int, int],
                    corner_rc: tuple[int, int], pixel_size_um: float, far_field: bool = False
                    ) -> tuple[np.ndarray, np.ndarray]:
    """A fitted particle's recorded field on a crop's pixels, its alpha applied.

    Parameters
    ----------
    theory, model, optics
        The neighbour's engine, particle (static parameters settled) and illumination.
    values : dict
        The neighbour's fit row (``x_um, y_um, z_um``, orientation angles, ``alpha``, um and
        rad; its static parameters where the row has them; the objective's NA if the fit
        varied it).
    crop_shape, corner_rc, pixel_size_um
        The crop the field is wanted on: shape, full-frame corner (row, column), pitch (um).
    far_field : bool
        As the frame fit's setting.

    Returns
    -------
    tuple of ndarray
        ``alpha * (Ex, Ey)`` of shape ``crop_shape`` (incident-field units).
    """
    state = state_of(values, model)
    na = values.get(APERTURE.name)
    if na is not None and np.isfinite(na):
        state = replace(state, numerical_aperture=float(na))
    pix = select_pixels(np.zeros(crop_shape), corner_rc, pixel_size_um)
    m = HologramModel(theory, ParameterSpace(model, [], state), optics, pix.xs_um, pix.ys_um,
                      far_field=far_field)
    ex, ey = m.fields(state)
    return ((state.alpha * ex).reshape(crop_shape), (state.alpha * ey).reshape(crop_shape))


@dataclass(frozen=True)
class OverlapPayload:
    """What the driver sends a worker for one refit."""

    crop: np.ndarray
    corner: tuple[int, int]
    own: dict[str, float]
    neighbour: int
    neighbour_values: dict[str, float]
    time_s: float
    #: the neighbour's pass (its model) where it is not the refitted row's own
    neighbour_config: PassConfig | None = None


@dataclass(frozen=True)
class Neighbours:
    """The rows whose fields stand for the neighbours in another model's refits.

    A run that tests several models fits every track with each; a track's row refitted with
    its neighbour's field needs that neighbour's field as well fitted as it can be, not as the
    refitted model describes it (a rod fitted as a sphere leaves its rings in its neighbour's
    crop, and the neighbour's sphere fit then looks worse than it is).

    Attributes
    ----------
    config : PassConfig
        The neighbours' pass (their model, statics and engine; no T-matrix).
    table : pandas.DataFrame
        Its rows, keyed by ``(particle, frame)``.
    """

    config: PassConfig
    table: pd.DataFrame


def _direct(config: PassConfig, track: int) -> PassConfig:
    """The pass as ``track`` sees it, with direct solves (the refit moves no static
    parameter, but its neighbour's field is added; no T-matrix needed)."""
    return replace(config.for_track(track), tmatrix=None, seed_tmatrix=None)


def refit_overlap_task(config: PassConfig, key: tuple[int, int],
                       payload: OverlapPayload) -> dict[str, Any]:
    """Refit one overlapping (particle, frame) row with its neighbour's field; the item
    function of the batch."""
    p, f = int(key[0]), int(key[1])
    q = payload.neighbour
    inst = config.instrument
    mine, theirs = _direct(config, p), _direct(payload.neighbour_config or config, q)
    extra = neighbour_field(item_theory(theirs), theirs.particle.model, inst.optics,
                            payload.neighbour_values, payload.crop.shape, payload.corner,
                            inst.pixel_size_um, config.options.far_field)
    model = mine.particle.model
    problem = FrameProblem(payload.crop, payload.corner, inst.pixel_size_um,
                           item_theory(mine), model, inst.optics, mine.free, mine.options,
                           seed=f, extra_field=extra)
    res = fit_frame_warm(problem, state_of(payload.own, model)).result
    row = {"particle": p, **result_row(f, payload.time_s, res), "model": model.kind}
    row["message"] = (f"refitted with track {q}'s field"
                      + (f": {row['message']}" if row.get("message") else ""))
    return row


def _placed(row: pd.Series) -> dict[str, float] | None:
    """A fit row's numeric values, or None if it has no fitted placement (skipped, failed)."""
    values = {k: float(v) for k, v in row.items()
              if isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool)}
    if row.get("status") == SKIPPED or not all(
            np.isfinite(values.get(k, np.nan)) for k in ("x_um", "y_um", "z_um", "alpha")):
        return None
    return values


def overlap_rows(crops: CropSet) -> pd.DataFrame:
    """The crop rows marked ``overlap``: particle, frame, neighbour, neighbour_px."""
    table = crops.table
    if "overlap" not in table.columns:
        return pd.DataFrame(columns=["particle", "frame", "neighbour", "neighbour_px"])
    marked = table["overlap"].astype(str).str.lower().isin(["true", "1"])
    return table.loc[marked, ["particle", "frame", "neighbour", "neighbour_px"]]


def refit_overlaps(table: pd.DataFrame, crops: CropSet, config: PassConfig, output: Path,
                   batch: BatchSettings | None = None, neighbours: Neighbours | None = None
                   ) -> tuple[pd.DataFrame, int, int, BatchSummary | None]:
    """Refit a pass's overlapping rows with their neighbour's field.

    Parameters
    ----------
    table : DataFrame
        Every track's rows of one pass, keyed by ``(particle, frame)``.
    crops : CropSet
        The crop folder (its rows marked ``overlap``: :func:`overlap_rows`).
    config : PassConfig
        The pass (the final pass's: each track's settled statics).
    output : Path
        The batch's table.
    batch : BatchSettings, optional
        Backend and resumption.
    neighbours : Neighbours, optional
        Where the neighbours' fields come from, if not from ``table`` itself (another model's
        pass of the same tracks).

    Returns
    -------
    table, n_refit, n_ok, summary
        The table with refitted rows (each refit replaces its row; one that failed leaves
        the row as it was, its message saying why); how many were refitted, how many of
        them are ``ok``; the batch's summary (None: nothing to refit).
    """
    overlaps = overlap_rows(crops)
    rows = {(int(r["particle"]), int(r["frame"])): i for i, r in table.iterrows()}
    source = neighbours.table if neighbours is not None else table
    their_rows = (rows if neighbours is None else
                  {(int(r["particle"]), int(r["frame"])): i for i, r in source.iterrows()})
    items: dict[tuple[int, int], tuple[int, dict[str, float], dict[str, float]]] = {}
    for o in overlaps.itertuples():
        p, f, q = int(o.particle), int(o.frame), int(o.neighbour)
        mine, theirs = rows.get((p, f)), their_rows.get((q, f))
        if mine is None or theirs is None:
            continue
        own, them = _placed(table.loc[mine]), _placed(source.loc[theirs])
        if own is not None and them is not None:
            items[(p, f)] = (q, own, them)
    if not items:
        return table, 0, 0, None
    columns = pass_columns(config)

    def load(key: tuple[int, int]) -> OverlapPayload:
        q, own, them = items[key]
        crow = crops.row(key)
        return OverlapPayload(crops.crop(key), (int(crow["corner_row"]), int(crow["corner_col"])),
                              own, q, them, float(own.get("time_s", math.nan)),
                              neighbours.config if neighbours is not None else None)

    key = fingerprint({"config": config.as_dict(), "crops": crops.fingerprint(),
                       "neighbours": (neighbours.config.as_dict() if neighbours is not None
                                      else None),
                       "items": {f"{k[0]},{k[1]}": [v[0], _rounded(v[1]), _rounded(v[2])]
                                 for k, v in sorted(items.items())}})
    meta = sidecar(kind=f"overlapping rows of the {config.pass_name} pass refitted with the "
                        "neighbour's field", config=config.as_dict(), inputs=[crops.table_path])
    # refits of other first fits (a track refitted since, say) are derived rows: redone
    stage_table = StageTable(output, columns, meta, key, f"fit ({config.pass_name}, overlaps)",
                             key_columns=PARTICLE_KEY, replace_stale=True)
    summary, _ = run_stage(refit_overlap_task, config, sorted(items), load, stage_table,
                           batch=batch)
    out, n_refit, n_ok = _merged(table, rows, read_table(output), items)
    return out, n_refit, n_ok, summary


def _rounded(values: dict[str, float]) -> dict[str, float]:
    """A row's values as the fingerprint holds them (the CSV's round trip)."""
    return {k: float(f"{v:.10g}") for k, v in sorted(values.items()) if k != "fit_time_s"}


def _merged(table: pd.DataFrame, rows: dict[tuple[int, int], int], refits: pd.DataFrame,
            items: dict[tuple[int, int], Any]) -> tuple[pd.DataFrame, int, int]:
    """``table`` with the batch's refits in place of their rows."""
    out = table.copy()
    for k in refits.columns:
        # a text column read back empty is float (all NaN): the refits' text goes in as text
        if (k in out.columns and not pd.api.types.is_numeric_dtype(refits[k])
                and pd.api.types.is_numeric_dtype(out[k])):
            out[k] = out[k].astype(object)
    n_refit = n_ok = 0
    for _, new in refits.iterrows():
        key = (int(new["particle"]), int(new["frame"]))
        if key not in items:
            continue
        at = rows[key]
        if new["status"] == ERROR:
            out.at[at, "message"] = (f"refit with track {items[key][0]}'s field failed: "
                                     f"{new['message']}")
            continue
        for k, v in new.items():
            if k in out.columns and k != "particle":
                out.at[at, k] = v
        n_refit += 1
        n_ok += int(new["status"] == OK)
    return out, n_refit, n_ok


def mark_overlap(table: pd.DataFrame, overlaps: pd.DataFrame) -> pd.DataFrame:
    """Rows whose crop overlaps another track's hologram (``overlaps``: the crop rows marked
    so, :func:`overlap_rows`) and whose fit is not ``ok`` (nor ``skipped``) get status
    ``overlap``, the old status and message kept in the message; the others are unchanged."""
    if overlaps.empty:
        return table
    marks = {(int(r.particle), int(r.frame)): (int(r.neighbour), float(r.neighbour_px))
             for r in overlaps.itertuples()}
    out = table.copy()
    for i, row in out.iterrows():
        hit = marks.get((int(row["particle"]), int(row["frame"])))
        if hit is None or row["status"] in (OK, SKIPPED):
            continue
        msg = "" if pd.isna(row.get("message")) else str(row.get("message"))
        out.at[i, "status"] = OVERLAP
        out.at[i, "message"] = (f"track {hit[0]}'s hologram overlaps ({hit[1]:.0f} px away); "
                                f"fit {row['status']}" + (f": {msg}" if msg else ""))
    return out
