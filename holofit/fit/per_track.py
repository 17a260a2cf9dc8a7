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

Frames whose crop another track's hologram overlaps (the crop table's ``overlap``):

- each track's initial pass fits its frames without a neighbour's hologram first (the
  fit stage's choice of initial frames); a track that has too few such frames fits
  overlapping ones too;
- once every track's pass is done, its overlapping rows are fitted again with the neighbour
  track's field at that frame (its row of the same pass) added to the model's
  (:mod:`holofit.fit.overlaps`: one batch per pass, ``OUT/overlaps/initial.csv`` and
  ``OUT/overlaps/fit.csv``, parallel and resumable). The refits replace the rows of
  ``OUT/initial.csv`` and ``OUT/fit.csv`` (the per-track tables keep the first fits). The
  static parameters are averaged after the initial round (each track's ``static.json``
  rewritten from its rows of ``OUT/initial.csv``), so a track whose every initial frame
  overlaps still gets sound static parameters;
- overlapping final rows that are still not ``ok`` become ``overlap`` (:func:`mark_overlap`;
  ``holofit analyze`` uses ``ok`` rows only).

A crop folder of one track is fitted exactly as before, into ``OUT`` itself.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pandas as pd

from holofit.config import ParticleConfig
from holofit.fit.errors import FitStageError
from holofit.fit.overlaps import OverlapRefit, overlap_table, refit_overlaps
from holofit.fit.stage import FitRun, run_fit
from holofit.fit.static import write_static
from holofit.io.tables import read_table, sidecar_path, write_json, write_table
from holofit.status import OK, OVERLAP, SKIPPED
from holofit.tables.cropset import CropSet, write_track_view
from holofit.tables.inputs import read_stage_table

__all__ = ["STATIC_MODES", "mark_overlap", "run_fit_tracks", "track_dir"]

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
    combined = FitRun()
    pass_name = kwargs.pop("pass_name", "both")
    given = kwargs.get("static")
    statics: dict[int, Path] = {}
    if given is not None:
        statics = {p: Path(given) for p in views}
    elif static == "pooled" and pass_name == "final":  # make's second call: the pooled file
        statics = {p: out / "static.json" for p in views}
    if pass_name in ("both", "initial"):
        first = {p: _initial_run(vdir, pre, lib, particle, track_dir(out, p),
                                 {**kwargs, **cut[p]})
                 for p, (vdir, pre, lib) in views.items()}
        _merge(combined, first, "initial")
        initial = _combine(first, "initial", out, "initial.csv",
                           refit=_refit_round(combined, overlaps, crop_dir, particle, "initial",
                                              out, None, kwargs))
        if initial is None:
            raise FitStageError("the initial pass of some track wrote no table")
        combined.initial = initial
        found = _statics(initial, first, particle, out, static)
        combined.static = found.pop(-1)
        if static == "pooled":
            combined.notes.append(f"static parameters pooled over {len(views)} tracks -> "
                                  f"{combined.static}")
        if given is None:
            statics = found
        if pass_name == "initial":
            return combined
    runs: dict[int, FitRun] = {}
    for p, (vdir, pre, lib) in views.items():
        runs[p] = run_fit(vdir, pre, lib, particle, track_dir(out, p), pass_name="final",
                          **{**kwargs, **cut[p], **({"static": statics[p]} if p in statics
                                                    else {})})
    _merge(combined, runs, "final")
    combined.final = _combine(runs, "final", out, "fit.csv", overlaps,
                              _refit_round(combined, overlaps, crop_dir, particle, "final", out,
                                           lambda p: statics.get(p, track_dir(out, p) /
                                                                 "static.json"), kwargs))
    return combined


def _initial_run(vdir: Path, pre: Path | None, lib: Path | None, particle: ParticleConfig,
                 tdir: Path, kwargs: dict[str, Any]) -> FitRun:
    """A track's initial pass. A pass with no ``ok`` frame (every frame pulled off by a
    neighbour's overlapping hologram, say) keeps its table: the overlap refit may mend it,
    and the static parameters are averaged after that (:func:`_statics`)."""
    try:
        return run_fit(vdir, pre, lib, particle, tdir, pass_name="initial", **kwargs)
    except FitStageError as exc:  # static.py's "no ok frame", with the table to show it
        table = tdir / "initial.csv"
        if ("no ok frame" not in str(exc) or not table.exists()
                or (read_table(table)["status"] == OK).any()):
            raise
        return FitRun(initial=table)


def _statics(initial: Path, first: dict[int, FitRun], particle: ParticleConfig, out: Path,
             mode: str) -> dict[int, Path]:
    """The static parameters from the combined initial table (overlapping rows refitted):
    pooled (``OUT/static.json`` for every track), or each track's own (its
    ``static.json``, rewritten from its combined rows; ``OUT/static.json`` the index). The
    index is under key ``-1``."""
    table = read_table(initial)
    model = particle.model
    if mode == "pooled":
        try:
            pooled = write_static(out / "static.json", initial, table, model)
        except FitStageError as exc:
            raise FitStageError(f"pooled static parameters: {exc}") from None
        return {**{p: pooled for p in first}, -1: pooled}
    found: dict[int, Path] = {}
    for p, run in first.items():
        try:
            found[p] = write_static(track_dir(out, p) / "static.json", initial,
                                    table[table["particle"] == p], model)
        except FitStageError as exc:
            raise FitStageError(f"particle {p}: {exc}") from None
        run.static = found[p]
    index = _static_index(first, out)
    assert index is not None
    return {**found, -1: index}


def _refit_round(combined: FitRun, overlaps: pd.DataFrame, crop_dir: Path,
                 particle: ParticleConfig, pass_name: str, out: Path,
                 statics_of: Callable[[int], Path] | None, kwargs: dict[str, Any]
                 ) -> Callable[[pd.DataFrame], pd.DataFrame] | None:
    """The overlap refit of one pass's combined table (:mod:`holofit.fit.overlaps`), or None
    where no crop overlaps."""
    if overlaps.empty:
        return None

    def refit(table: pd.DataFrame) -> pd.DataFrame:
        table_name = "fit" if pass_name == "final" else pass_name
        how = OverlapRefit(crop_dir, particle, pass_name, overlap_table(out, table_name),
                           statics_of, kwargs)
        table, n_refit, n_ok = refit_overlaps(table, overlaps, how)
        if how.summary is not None:
            combined.summaries[f"{pass_name}, overlaps"] = how.summary
        combined.notes.append(f"{pass_name} pass: overlapping frames refitted with the "
                              f"neighbour's field: {n_refit} ({n_ok} ok)")
        return table
    return refit


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
