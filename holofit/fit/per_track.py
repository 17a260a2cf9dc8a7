"""``holofit fit`` on a crop folder of several tracks: the fit of each track, then one table.

A crop folder made in the crop stage's tracks mode with more than one track is keyed by
``(particle, frame)`` (:mod:`holofit.tables.cropset`). Each track is fitted by the one-particle
fit (:func:`holofit.fit.stage.run_fit`) on its own *view* of the crops
(:func:`holofit.tables.cropset.write_track_view`), with the prefit's and the library's rows of
that track, into ``OUT/particle_<p>/``; each track's run is resumable on its own. Then
``OUT/initial.csv`` and ``OUT/fit.csv`` (+ sidecars, written atomically) hold every track's rows
with the column ``particle`` in front, in the fit-table schema (:mod:`holofit.tables.fit`).

Static parameters (``static_mode``):

- ``"per-track"`` (the default): each track's own initial pass and ``static.json`` (tracks of
  different particles: a rod and a dimer, or rods of different lengths);
- ``"pooled"``: each track's initial pass, then one robust average over the ``ok`` rows of all
  of them (``OUT/static.json``), which every track's final pass uses (one batch of identical
  particles).

Frames whose crop another track's hologram overlaps (the crop table's ``overlap``) are fitted
a second time once every track's final pass is done (:func:`refit_overlaps`): where the
neighbour track has a fitted row at that frame (a finite placement, whatever its status), its
recorded field on this crop's pixels (its
fitted position, orientation, alpha and static parameters, through the same engine) is a fixed
field added to the model's before the intensity (:mod:`holofit.holomodel.forward`,
``extra_field``), and the frame is refitted from its first fit (:func:`holofit.fit.frame.
fit_frame_warm`). The refit replaces the row in ``OUT/fit.csv`` (the per-track tables keep the
first fit). Overlapping frames that are still not ``ok`` become ``overlap``
(:func:`mark_overlap`; ``holofit analyze`` uses ``ok`` rows only).

A crop folder of one track is fitted exactly as before, into ``OUT`` itself.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from holofit.batch.aperture import FROM_INSTRUMENT
from holofit.batch.stage import stage_inputs
from holofit.config import ParticleConfig
from holofit.fit.errors import FitStageError
from holofit.fit.frame import FrameFitSettings, fit_frame_warm
from holofit.fit.stage import FitRun, run_fit
from holofit.fit.static import read_static, write_static
from holofit.fit.task import FitConfig
from holofit.fit.tracking import state_of
from holofit.holomodel.forward import HologramModel
from holofit.holomodel.parameters import APERTURE, ParameterSpace, particle_with
from holofit.holomodel.pixels import select_pixels
from holofit.holomodel.result import result_row
from holofit.io.tables import read_table, sidecar_path, write_json, write_table
from holofit.optics import Optics
from holofit.particles import ParticleModel
from holofit.scattering.theory import ScatteringTheory
from holofit.status import OK, OVERLAP, SKIPPED
from holofit.tables.cropset import CropSet, write_track_view
from holofit.tables.inputs import read_stage_table

__all__ = ["STATIC_MODES", "mark_overlap", "neighbour_field", "refit_overlaps",
           "run_fit_tracks", "track_dir"]

#: how the static parameters of several tracks are found
STATIC_MODES = ("per-track", "pooled")


def track_dir(out_dir: str | Path, particle: int) -> Path:
    """Where track ``particle``'s fit goes."""
    return Path(out_dir) / f"particle_{particle}"


def _track_table(path: Path | None, crops: CropSet, what: str, particle: int,
                 view: CropSet, out: Path) -> Path | None:
    """Track ``particle``'s rows of a prefit or library table (checked against the whole
    crop folder), written for its view (``out/<what>.csv``, sidecar naming the view)."""
    if path is None:
        return None
    table, meta = read_stage_table(path, crops, what)
    rows = table[table["particle"] == particle].drop(columns="particle").reset_index(drop=True)
    meta = dict(meta)
    for where in (meta, meta.get("extra")):  # the sidecar names the crops it was made from
        if isinstance(where, dict) and "crops" in where:
            where["crops"] = view.fingerprint()
    meta["track_of"] = {"table": str(path), "particle": int(particle)}
    target = out / f"{what}.csv"
    write_table(target, rows, meta)
    return target


def _combine(runs: dict[int, FitRun], attr: str, out: Path, name: str,
             overlaps: pd.DataFrame | None = None,
             refit: Callable[[pd.DataFrame], pd.DataFrame] | None = None) -> Path | None:
    """Every track's table ``attr`` (initial or final) as one table with ``particle`` first."""
    parts, meta = [], None
    for p, run in runs.items():
        path = getattr(run, attr)
        if path is None or not Path(path).exists():
            return None
        parts.append(read_table(path).assign(particle=p))
        if meta is None:
            with contextlib.suppress(OSError, ValueError):
                import json

                meta = json.loads(sidecar_path(path).read_text())
    table = pd.concat(parts, ignore_index=True)
    table = table[["particle", *[c for c in table.columns if c != "particle"]]]
    if refit is not None:
        table = refit(table)
    if overlaps is not None:
        table = mark_overlap(table, overlaps)
    meta = dict(meta or {})
    meta["units"] = {"particle": "track id (the crop stage's tracks mode)",
                     **dict(meta.get("units") or {})}
    meta["extra"] = {**dict(meta.get("extra") or {}),
                     "tracks": {str(p): str(getattr(r, attr)) for p, r in runs.items()}}
    return write_table(out / name, table, meta)


def run_fit_tracks(crop_dir: str | Path, prefit: str | Path, library: str | Path | None,
                   particle: ParticleConfig, out_dir: str | Path, *, static_mode: str = "per-track",
                   tracks: list[int] | None = None, **kwargs: Any) -> FitRun:
    """Fit every track of a crop folder (see the module docstring).

    Parameters
    ----------
    crop_dir, prefit, library, particle, out_dir
        As for :func:`holofit.fit.stage.run_fit`.
    static_mode : {"per-track", "pooled"}
        Static parameters per track, or pooled over the tracks.
    tracks : list of int, optional
        Only these tracks (default: all).
    **kwargs
        Passed to :func:`~holofit.fit.stage.run_fit` for every track.

    Returns
    -------
    FitRun
        ``initial`` and ``final``: the combined tables; ``summaries`` per pass and track.

    Raises
    ------
    FitStageError
        An unknown ``static`` mode or track, or (pooled) no ``ok`` initial row at all.
    """
    if static_mode not in STATIC_MODES:
        raise FitStageError(f"static mode {static_mode!r}: expected one of "
                            f"{', '.join(STATIC_MODES)}")
    with CropSet(crop_dir) as crops:
        if not crops.multi:
            return run_fit(crop_dir, prefit, library, particle, out_dir, **kwargs)
        ids = crops.particles if tracks is None else list(tracks)
        unknown = sorted(set(ids) - set(crops.particles))
        if unknown:
            raise FitStageError(f"{crops.table_path}: no track(s) {unknown} (tracks: "
                                f"{', '.join(map(str, crops.particles))})")
        out = Path(out_dir)
        views: dict[int, tuple[Path, Path | None, Path | None]] = {}
        for p in ids:
            tdir = track_dir(out, p)
            vdir = write_track_view(crops, p, tdir / "crops")
            with CropSet(vdir) as view:
                pre = _track_table(Path(prefit), crops, "prefit", p, view, tdir)
                lib = _track_table(None if library is None else Path(library), crops,
                                   "library", p, view, tdir)
            views[p] = (vdir, pre, lib)
    return _fit_views(views, particle, out, static_mode, kwargs, _frames_of(crops, ids, kwargs),
                      _overlaps(crops), Path(crop_dir))


def _overlaps(crops: CropSet) -> pd.DataFrame:
    """The crop rows marked ``overlap``: particle, frame, neighbour, neighbour_px."""
    table = crops.table
    if "overlap" not in table.columns:
        return pd.DataFrame(columns=["particle", "frame", "neighbour", "neighbour_px"])
    marked = table["overlap"].astype(str).str.lower().isin(["true", "1"])
    return table.loc[marked, ["particle", "frame", "neighbour", "neighbour_px"]]


def mark_overlap(table: pd.DataFrame, overlaps: pd.DataFrame) -> pd.DataFrame:
    """Rows of a combined fit table whose crop overlaps another track's hologram and whose
    fit is not ``ok`` (nor ``skipped``) get status ``overlap``, the old status and message
    kept in the message; the others are unchanged."""
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


def _frames_of(crops: CropSet, ids: list[int], kwargs: dict[str, Any]
               ) -> dict[int, dict[str, Any]]:
    """Per track, ``frames`` and ``plot_frames`` cut to the track's frames (a frame range
    asked for may start before a track enters)."""
    table = crops.table
    out: dict[int, dict[str, Any]] = {}
    for p in ids:
        have = set(int(f) for f in table.loc[table["particle"] == p, "frame"])
        out[p] = {k: [f for f in kwargs[k] if f in have] for k in ("frames", "plot_frames")
                  if kwargs.get(k) is not None}
    return out


def _fit_views(views: dict[int, tuple[Path, Path | None, Path | None]],
               particle: ParticleConfig, out: Path, static: str,
               kwargs: dict[str, Any], cut: dict[int, dict[str, Any]],
               overlaps: pd.DataFrame, crop_dir: Path) -> FitRun:
    runs: dict[int, FitRun] = {}
    combined = FitRun()
    pass_name = kwargs.pop("pass_name", "both")
    if static == "pooled" and pass_name in ("both", "initial") and kwargs.get("static") is None:
        for p, (vdir, pre, lib) in views.items():
            runs[p] = run_fit(vdir, pre, lib, particle, track_dir(out, p), pass_name="initial",
                              **{**kwargs, **cut[p]})
        initial = _combine(runs, "initial", out, "initial.csv")
        if initial is None:
            raise FitStageError("the initial pass of some track wrote no table")
        try:
            pooled = write_static(out / "static.json", initial, read_table(initial),
                                  particle.model)
        except FitStageError as exc:
            raise FitStageError(f"pooled static parameters: {exc}") from None
        combined.static, combined.initial = pooled, initial
        combined.notes.append(f"static parameters pooled over {len(views)} tracks -> {pooled}")
        _merge(combined, runs, "initial")
        if pass_name == "initial":
            return combined
        kwargs = {**kwargs, "static": pooled}
        pass_name = "final"
    for p, (vdir, pre, lib) in views.items():
        runs[p] = run_fit(vdir, pre, lib, particle, track_dir(out, p), pass_name=pass_name,
                          **{**kwargs, **cut[p]})
    _merge(combined, runs, "final" if pass_name == "final" else None)
    if combined.initial is None:
        combined.initial = _combine(runs, "initial", out, "initial.csv")
    if combined.static is None and pass_name in ("both", "initial"):
        combined.static = _static_index(runs, out)
    refit = None
    if not overlaps.empty and pass_name in ("both", "final"):
        def statics_of(p: int) -> Path:
            given = kwargs.get("static")
            return Path(given) if given is not None else track_dir(out, p) / "static.json"

        def refit(table: pd.DataFrame) -> pd.DataFrame:
            table, n_refit, n_ok = refit_overlaps(table, overlaps, crop_dir, particle,
                                                  statics_of, kwargs)
            combined.notes.append(f"overlapping frames refitted with the neighbour's field: "
                                  f"{n_refit} ({n_ok} ok)")
            return table
    combined.final = _combine(runs, "final", out, "fit.csv", overlaps, refit)
    return combined


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
        rad; the objective's NA if the fit varied it).
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


def refit_overlaps(table: pd.DataFrame, overlaps: pd.DataFrame, crop_dir: Path,
                   particle: ParticleConfig, statics_of: Callable[[int], Path],
                   kwargs: dict[str, Any]) -> tuple[pd.DataFrame, int, int]:
    """Refit a combined fit table's overlapping rows with their neighbour's field.

    Each (particle, frame) of ``overlaps`` whose neighbour track has a fitted row at that
    frame (any status with a finite placement: two overlapping first fits are both pulled
    off, and usually both ``poor_fit``), and whose own row has one too, is fitted again
    (final-pass parameters, warm from its own row) with the neighbour's field
    (:func:`neighbour_field`) added to the model; the new row replaces the old one, its
    message naming the neighbour.

    Parameters
    ----------
    table : DataFrame
        Every track's final-pass rows, ``particle`` first.
    overlaps : DataFrame
        The crop rows marked ``overlap`` (particle, frame, neighbour, neighbour_px).
    crop_dir : Path
        The crop folder (keyed by particle and frame).
    particle : ParticleConfig
        The particle configuration the tracks were fitted with.
    statics_of : callable
        Track id -> the ``static.json`` its final pass used.
    kwargs : dict
        :func:`~holofit.fit.stage.run_fit`'s keyword arguments (instrument, options, engine,
        fixed, fit_na, numerical_aperture, override_instrument).

    Returns
    -------
    table, n_refit, n_ok
        The table with refitted rows; how many were refitted, and how many of them are ``ok``.
    """
    opts = kwargs.get("options") or FrameFitSettings()
    fit_na = bool(kwargs.get("fit_na", False))
    rows = {(int(r["particle"]), int(r["frame"])): i for i, r in table.iterrows()}
    out = table.copy()
    n_refit = n_ok = 0
    with stage_inputs(crop_dir, None, kwargs.get("instrument"),
                      bool(kwargs.get("override_instrument", False)),
                      kwargs.get("numerical_aperture", FROM_INSTRUMENT), fit_na) as given:
        settle = _Settled(particle, statics_of, kwargs.get("engine"), given.instrument)
        free = FitConfig(particle, given.instrument, "final", opts, kwargs.get("engine"),
                         tuple(kwargs.get("fixed", ())), fit_na=fit_na).free
        for o in overlaps.itertuples():
            p, f, q = int(o.particle), int(o.frame), int(o.neighbour)
            mine, theirs = rows.get((p, f)), rows.get((q, f))
            if mine is None or theirs is None:
                continue
            own, them = _placed(table.loc[mine]), _placed(table.loc[theirs])
            if own is None or them is None:
                continue
            new = _refit_row(given, settle, (p, f, q), own, them, free, opts,
                             float(table.at[mine, "time_s"]))
            if isinstance(new, str):
                out.at[mine, "message"] = new
                continue
            for k, v in new.items():
                if k in out.columns:
                    out.at[mine, k] = v
            n_refit += 1
            n_ok += int(new["status"] == OK)
    return out, n_refit, n_ok


class _Settled:
    """Each track's particle with the static parameters its final pass used, and its engine
    (built once per track)."""

    def __init__(self, particle: ParticleConfig, statics_of: Callable[[int], Path],
                 engine: str | None, inst: Any) -> None:
        self.particle, self.statics_of, self.engine, self.inst = particle, statics_of, engine, inst
        self.done: dict[int, tuple[ParticleModel, ScatteringTheory]] = {}

    def __call__(self, p: int) -> tuple[ParticleModel, ScatteringTheory]:
        if p not in self.done:
            model = self.particle.model
            cfg = ParticleConfig(particle_with(model, read_static(self.statics_of(p), model)),
                                 self.particle.settings, self.particle.path)
            self.done[p] = (cfg.model, cfg.theory(self.engine,
                                                  fixed_lattice_for=self.inst.optics))
        return self.done[p]


def _refit_row(given: Any, settle: _Settled, pfq: tuple[int, int, int], own: Any, them: Any,
               free: Any, opts: FrameFitSettings, time_s: float) -> dict[str, Any] | str:
    """One overlapping row refitted with its neighbour's field: the new row, or why not."""
    p, f, q = pfq
    inst = given.instrument
    crow = given.crops.row((p, f))
    corner = (int(crow["corner_row"]), int(crow["corner_col"]))
    crop = given.crops.crop((p, f))
    model_q, theory_q = settle(q)
    extra = neighbour_field(theory_q, model_q, inst.optics, them, crop.shape, corner,
                            inst.pixel_size_um, opts.far_field)
    model_p, theory_p = settle(p)
    try:
        res = fit_frame_warm(crop, corner, inst.pixel_size_um, theory_p, model_p, inst.optics,
                             state_of(own, model_p), free, opts, seed=f,
                             extra_field=extra).result
    except ValueError as exc:
        return f"refit with track {q}'s field failed: {exc}"
    new = result_row(f, time_s, res)
    new["message"] = (f"refitted with track {q}'s field"
                      + (f": {new['message']}" if new.get("message") else ""))
    return new


def _static_index(runs: dict[int, FitRun], out: Path) -> Path | None:
    """``OUT/static.json`` of per-track static parameters: each track's values and where its
    own ``static.json`` is (the file ``make`` waits for after the initial pass)."""
    import json

    tracks = {}
    for p, run in runs.items():
        if run.static is None or not Path(run.static).exists():
            return None
        doc = json.loads(Path(run.static).read_text())
        tracks[str(p)] = {"file": str(run.static),
                          **{k: doc[k] for k in ("values", "spread", "n_frames") if k in doc}}
    path = out / "static.json"
    write_json(path, {"kind": "static parameters per track (each track's final pass uses its "
                              "own static.json)", "static_mode": "per-track", "tracks": tracks})
    return path


def _merge(combined: FitRun, runs: dict[int, FitRun], only: str | None) -> None:
    """Each track's summaries and notes into ``combined``, named by track."""
    for p, run in runs.items():
        for name, s in run.summaries.items():
            if only is None or name == only:
                combined.summaries[f"{name}, particle {p}"] = s
        combined.notes += [f"particle {p}: {n}" for n in run.notes]


def _placed(row: pd.Series) -> dict[str, float] | None:
    """A fit row's numeric values, or None if it has no fitted placement (skipped, failed)."""
    values = {k: float(v) for k, v in row.items()
              if isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool)}
    if row.get("status") == SKIPPED or not all(
            np.isfinite(values.get(k, np.nan)) for k in ("x_um", "y_um", "z_um", "alpha")):
        return None
    return values
