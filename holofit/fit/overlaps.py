"""Overlapping (particle, frame) rows refitted with the neighbour's field, as a batch.

Where two tracks' holograms overlap (the crop table's ``overlap``), each track's first fit
is pulled off by the other's rings. Each such row whose neighbour track has a fitted row at
that frame (a finite placement, whatever its status: two overlapping first fits are both
pulled off and usually ``poor_fit``) is fitted again, warm from its own row, with the
neighbour's recorded field on the crop's pixels (:func:`neighbour_field`: its fitted
position, orientation, alpha and static parameters, through the same engine) added to the
model's field before the intensity (:mod:`holofit.holomodel.forward`, ``extra_field``).

The refits are the items of one batch (:func:`holofit.batch.runner.run_batch`) keyed by
``(particle, frame)``, one table per pass (``overlaps/<pass>.csv`` beside the combined
table): parallel (``-j``, Dask), journalled, and a rerun resumes without redoing a finished
row; its fingerprint holds both rows of every item, so new first fits (a track refitted
since) start the batch afresh, discarding the earlier refits.
The same round serves both passes: the final pass's rows (static parameters each track's
settled values) and the initial pass's (static parameters free, each row's own).
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from holofit.batch.aperture import FROM_INSTRUMENT
from holofit.batch.runner import BatchOptions, BatchSummary, earlier_fingerprint, run_batch
from holofit.batch.stage import fingerprint, stage_inputs
from holofit.cache import LRUCache
from holofit.config import Instrument, ParticleConfig
from holofit.fit.frame import FrameFitSettings, fit_frame_warm
from holofit.fit.static import read_static
from holofit.fit.task import FitConfig, fit_columns
from holofit.fit.tracking import state_of
from holofit.holomodel.forward import HologramModel
from holofit.holomodel.parameters import APERTURE, ParameterSpace, particle_with
from holofit.holomodel.pixels import select_pixels
from holofit.holomodel.result import result_row
from holofit.io.tables import read_table
from holofit.optics import Optics
from holofit.particles import ParticleModel
from holofit.provenance import sidecar
from holofit.scattering.theory import ScatteringTheory
from holofit.status import ERROR, OK, SKIPPED

__all__ = ["OverlapConfig", "OverlapPayload", "OverlapRefit", "neighbour_field",
           "overlap_table", "refit_overlap_task", "refit_overlaps"]

#: the key columns of a refit batch
OVERLAP_KEY = ("particle", "frame")


def neighbour_field(theory: ScatteringTheory, model: ParticleModel, optics: Optics,
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
class OverlapConfig:
    """Everything a worker needs for the refits of one pass (picklable).

    Attributes
    ----------
    particle : ParticleConfig
        The particle the tracks were fitted with (its lattice fixed).
    instrument : Instrument
        Optics and pixel size.
    pass_name : {"initial", "final"}
        Which pass's rows: the free parameters are that pass's.
    statics : tuple
        ``(track, ((name, value), ...))`` per track: the static parameters its final pass
        used (empty for the initial pass, whose rows hold their own).
    options, engine, fixed, fit_na
        As for :class:`holofit.fit.task.FitConfig`.
    """

    particle: ParticleConfig
    instrument: Instrument
    pass_name: str
    statics: tuple[tuple[int, tuple[tuple[str, float], ...]], ...] = ()
    options: FrameFitSettings = field(default_factory=FrameFitSettings)
    engine: str | None = None
    fixed: tuple[str, ...] = ()
    fit_na: bool = False

    def fit_config(self, track: int) -> FitConfig:
        """The pass's :class:`FitConfig` of ``track`` (its settled particle in the final
        pass)."""
        particle = self.particle
        settled = dict(self.statics).get(track)
        if settled is not None:
            particle = ParticleConfig(particle_with(particle.model, dict(settled)),
                                      particle.settings, particle.path)
        return FitConfig(particle, self.instrument, self.pass_name, self.options, self.engine,
                         self.fixed, fit_na=self.fit_na)

    def as_dict(self) -> dict[str, Any]:
        return {"fit": self.fit_config(-1).as_dict(),
                "statics": {str(p): dict(s) for p, s in self.statics}}


@dataclass(frozen=True)
class OverlapPayload:
    """What the driver sends a worker for one refit."""

    crop: np.ndarray
    corner: tuple[int, int]
    own: dict[str, float]
    neighbour: int
    neighbour_values: dict[str, float]
    time_s: float


#: per worker process: one engine per (settled) particle, with its caches
_ENGINES: LRUCache[str, tuple[ParticleModel, ScatteringTheory]] = LRUCache(4)


def _engine(config: OverlapConfig, track: int) -> tuple[ParticleModel, ScatteringTheory]:
    cfg = config.fit_config(track)
    key = json.dumps({"particle": cfg.particle.as_dict(), "engine": cfg.engine},
                     sort_keys=True, default=str)
    optics = config.instrument.optics
    return _ENGINES.get_or_create(key, lambda: (
        cfg.particle.model, cfg.particle.theory(cfg.engine, fixed_lattice_for=optics)))


def refit_overlap_task(config: OverlapConfig, key: tuple[int, int],
                       payload: OverlapPayload) -> dict[str, Any]:
    """Refit one overlapping (particle, frame) row with its neighbour's field; the item
    function of the batch."""
    p, f = key
    q = payload.neighbour
    inst = config.instrument
    model_q, theory_q = _engine(config, q)
    extra = neighbour_field(theory_q, model_q, inst.optics, payload.neighbour_values,
                            payload.crop.shape, payload.corner, inst.pixel_size_um,
                            config.options.far_field)
    model_p, theory_p = _engine(config, p)
    res = fit_frame_warm(payload.crop, payload.corner, inst.pixel_size_um, theory_p, model_p,
                         inst.optics, state_of(payload.own, model_p),
                         config.fit_config(p).free, config.options, seed=f,
                         extra_field=extra).result
    row = result_row(f, payload.time_s, res)
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


@dataclass
class OverlapRefit:
    """How :func:`refit_overlaps` refits one pass's rows.

    Attributes
    ----------
    crop_dir : Path
        The crop folder (keyed by particle and frame).
    particle : ParticleConfig
        The particle configuration the tracks were fitted with.
    pass_name : {"initial", "final"}
        Which pass's rows.
    output : Path
        The batch's table (``<folder>/overlaps/<pass>.csv``).
    statics_of : callable, optional
        Final pass: track id -> the ``static.json`` its final pass used.
    kwargs : dict
        :func:`~holofit.fit.stage.run_fit`'s keyword arguments (instrument, options, engine,
        fixed, fit_na, numerical_aperture, override_instrument, batch).
    """

    crop_dir: Path
    particle: ParticleConfig
    pass_name: str
    output: Path
    statics_of: Callable[[int], Path] | None = None
    kwargs: dict[str, Any] | None = None
    summary: BatchSummary | None = None


def refit_overlaps(table: pd.DataFrame, overlaps: pd.DataFrame,
                   how: OverlapRefit) -> tuple[pd.DataFrame, int, int]:
    """Refit a combined fit table's overlapping rows with their neighbour's field.

    Parameters
    ----------
    table : DataFrame
        Every track's rows of one pass, ``particle`` first.
    overlaps : DataFrame
        The crop rows marked ``overlap`` (particle, frame, neighbour, neighbour_px).
    how : OverlapRefit
        The crop folder, particle, pass, batch table and settings.

    Returns
    -------
    table, n_refit, n_ok
        The table with refitted rows (each refit replaces its row; one that failed leaves
        the row as it was, its message saying why); how many were refitted, how many of
        them are ``ok``.
    """
    kw = dict(how.kwargs or {})
    opts = kw.get("options") or FrameFitSettings()
    fit_na = bool(kw.get("fit_na", False))
    rows = {(int(r["particle"]), int(r["frame"])): i for i, r in table.iterrows()}
    items: dict[tuple[int, int], tuple[int, dict[str, float], dict[str, float]]] = {}
    for o in overlaps.itertuples():
        p, f, q = int(o.particle), int(o.frame), int(o.neighbour)
        mine, theirs = rows.get((p, f)), rows.get((q, f))
        if mine is None or theirs is None:
            continue
        own, them = _placed(table.loc[mine]), _placed(table.loc[theirs])
        if own is not None and them is not None:
            items[(p, f)] = (q, own, them)
    if not items:
        return table, 0, 0
    with stage_inputs(how.crop_dir, None, kw.get("instrument"),
                      bool(kw.get("override_instrument", False)),
                      kw.get("numerical_aperture", FROM_INSTRUMENT), fit_na) as given:
        inst = given.instrument
        base = how.particle.with_fixed_lattice(inst.optics)
        statics: tuple[tuple[int, tuple[tuple[str, float], ...]], ...] = ()
        if how.pass_name == "final" and how.statics_of is not None:
            tracks = sorted({k[0] for k in items} | {v[0] for v in items.values()})
            statics = tuple((p, tuple(sorted(read_static(how.statics_of(p), base.model).items())))
                            for p in tracks)
        config = OverlapConfig(base, inst, how.pass_name, statics, opts, kw.get("engine"),
                               tuple(kw.get("fixed", ())), fit_na)
        columns = ("particle", *fit_columns(base.model, config.fit_config(-1).free))

        def load(key: tuple[int, int]) -> OverlapPayload:
            q, own, them = items[key]
            crow = given.crops.row(key)
            return OverlapPayload(given.crops.crop(key),
                                  (int(crow["corner_row"]), int(crow["corner_col"])),
                                  own, q, them, float(own.get("time_s", math.nan)))

        key = fingerprint({"config": config.as_dict(), "crops": given.crops.fingerprint(),
                           "items": {f"{k[0]},{k[1]}": [v[0], _rounded(v[1]), _rounded(v[2])]
                                     for k, v in sorted(items.items())}})
        meta = sidecar(kind=f"overlapping rows of the {how.pass_name} pass refitted with the "
                            "neighbour's field", config=config.as_dict(),
                       inputs=[given.crops.table_path])
        options = kw.get("batch") or BatchOptions()
        earlier = earlier_fingerprint(how.output)
        if earlier is not None and earlier != key:
            # refits of other first fits (a track refitted since, say): derived rows, redone
            options = replace(options, overwrite=True)
        how.summary = run_batch(refit_overlap_task, config, sorted(items), load, how.output,
                                columns, fingerprint=key, meta=meta, options=options,
                                desc=f"fit ({how.pass_name}, overlaps)", key_columns=OVERLAP_KEY)
    return _merged(table, rows, read_table(how.output), items)


def _rounded(values: dict[str, float]) -> dict[str, float]:
    """A row's values as the fingerprint holds them (the CSV's round trip)."""
    return {k: float(f"{v:.10g}") for k, v in sorted(values.items()) if k != "fit_time_s"}


def _merged(table: pd.DataFrame, rows: dict[tuple[int, int], int], refits: pd.DataFrame,
            items: dict[tuple[int, int], Any]) -> tuple[pd.DataFrame, int, int]:
    """``table`` with the batch's refits in place of their rows."""
    out = table.copy()
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


def overlap_table(out_dir: Path, pass_name: str) -> Path:
    """Where the refit batch of ``pass_name`` writes."""
    return Path(out_dir) / "overlaps" / f"{pass_name}.csv"
