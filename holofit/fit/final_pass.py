"""The final pass: every frame of every fitted track, its model's static parameters fixed.

Each track's model and statics come from ``static.json`` (:mod:`holofit.fit.static`). The
primary model's tracks are served from their T-matrix where the policy says so
(:mod:`holofit.fit.tmatrix_policy`; one per distinct set of statics) and, for an anisotropic
particle, followed from frame to frame (:meth:`FitPasses.followed_pass`); tracks given another
model of the run are fitted frame by frame (:meth:`FitPasses.frame_pass`). Then, on the whole
table: the continuity sweeps of the followed tracks (:mod:`holofit.fit.sweeps`), the overlap
refits, overlapping rows still not ``ok`` marked ``overlap``, a track left out by the
initial pass has ``skipped`` rows that say why, and the table's model error is estimated
(:mod:`holofit.fit.model_error`: the sidecar's ``model_error``). ``fit.csv`` is published
last; ``tracks.csv`` records each track's final counts.
"""

from __future__ import annotations

import json
from functools import partial
from pathlib import Path
from typing import Any

import pandas as pd

from holofit.batch.layout import publish_table, published_fingerprint
from holofit.batch.stage import fingerprint
from holofit.config import ParticleConfig
from holofit.fit.continuity import ContinuityReport
from holofit.fit.model_error import model_error_entry, model_error_note
from holofit.fit.overlaps import mark_overlap, overlap_rows
from holofit.fit.passes import FitPasses, load_payload, table_digest
from holofit.fit.static import TrackStatic, read_track_statics, static_doc
from holofit.fit.sweeps import SweepRun, continuity_sweeps
from holofit.fit.task import TrackSetup
from holofit.fit.tmatrix_policy import final_tmatrix
from holofit.fit.track_status import TrackOutcome, write_tracks
from holofit.holomodel.parameters import particle_with
from holofit.io.tables import read_table, sidecar_path
from holofit.particles import Sphere
from holofit.status import SKIPPED

__all__ = ["final_pass"]


def final_pass(fp: FitPasses, static_path: Path) -> None:
    """The final pass (module docstring), each track's model and statics from
    ``static_path``."""
    c, model = fp.config, fp.particle.model
    statics = read_track_statics(static_path, fp.tracks, model)
    setups = _setups(fp, {p: s for p, s in statics.items() if s.fitted})
    first = next((s for s in setups.values() if s.particle is None), TrackSetup())
    base = ParticleConfig(particle_with(model, dict(first.statics)), fp.particle.settings,
                          fp.particle.path)
    cfg = fp.pass_config("final", base, tmatrix=first.tmatrix).with_tracks(setups)
    primary = [k for k in fp.given.frames if k[0] in setups and setups[k[0]].particle is None]
    others = [k for k in fp.given.frames if k[0] in setups and setups[k[0]].particle is not None]
    followed = c.follow.warm and model.anisotropic
    parts, keys = [], []
    extra: dict[str, Any] = {}
    if followed and primary:
        table, key, extra = fp.followed_pass(cfg, primary)
        parts.append(table)
        keys.append(key)
        primary = []
    if primary or others:
        table, key, _ = fp.frame_pass(cfg, primary + others)
        parts.append(table)
        keys.append(key)
    parts.append(_left_out_rows(fp, statics))
    table = pd.concat([p for p in parts if len(p)], ignore_index=True)
    table = table.sort_values(["particle", "frame"]).reset_index(drop=True)
    docs = {str(p): static_doc(static_path, p) for p in fp.tracks}
    static = docs[str(fp.tracks[0])] if len(docs) == 1 else {"tracks": docs}
    path = fp.out / "fit.csv"
    key = fingerprint({"batch": keys, "rows": table_digest(table),
                       "continuity": c.continuity.__dict__,
                       "model_error": c.model_error.__dict__,
                       "overlaps": not overlap_rows(fp.given.crops).empty})
    if published_fingerprint(path) != key:
        meta = {**fp.meta(cfg, static), **extra}
        if c.continuity.enabled and model.anisotropic:
            table = _sweeps(fp, cfg, table, meta, key)
        table = fp.refit_overlaps(table, fp.overlap_config("final", setups), "final", "fit")
        table = mark_overlap(table, overlap_rows(fp.given.crops))
        entry = model_error_entry(fp, table, cfg, c.model_error)
        if entry is not None:
            meta["model_error"] = entry
        publish_table(path, table, meta, key)
    else:  # complete before this run: what the sweeps did, from its sidecar
        _continuity_from(fp, path)
        entry = json.loads(sidecar_path(path).read_text()).get("model_error")
    if entry is not None:
        fp.run.model_error = entry
        fp.run.notes.append(model_error_note(entry))
    fp.run.final = path
    _write_tracks(fp, statics, path)
    fp.pictures(path, cfg, "final", "fit")


def _setups(fp: FitPasses, fitted: dict[int, TrackStatic]) -> dict[int, TrackSetup]:
    """Each fitted track's setup: its statics and T-matrix (the primary model's tracks, one
    T-matrix per distinct set of statics), or its alternative model."""
    c, model = fp.config, fp.particle.model
    setups: dict[int, TrackSetup] = {}
    built: dict[tuple[tuple[str, float], ...], str | None] = {}
    primary = {p: s for p, s in fitted.items() if s.model == model.kind}
    shared = len({tuple(sorted(s.values.items())) for s in primary.values()}) <= 1
    for p, s in fitted.items():
        values = tuple(sorted(s.values.items()))
        if s.model != model.kind:
            setups[p] = TrackSetup(values, None, _alternative(fp, s.model), None)
            continue
        if values not in built:
            settled = ParticleConfig(particle_with(model, dict(values)), fp.particle.settings,
                                     fp.particle.path)
            name = "tmatrix.npz" if shared else f"tmatrix_p{p}.npz"
            tm = final_tmatrix(settled, fp.given.instrument, c.engine, c.tmatrix,
                               len(fp.keys_of(p)), fp.out, fp.local_workers(), name=name)
            fp.run.notes += tm.notes
            if tm.path is not None:
                fp.run.tmatrix = tm.path
                fp.run.tmatrix_s += tm.seconds
            built[values] = None if tm.path is None else str(tm.path)
        setups[p] = TrackSetup(values, built[values])
    return setups


def _alternative(fp: FitPasses, label: str) -> ParticleConfig:
    """The config of an alternative model of the run by its label (a sphere of the model
    test where the run names none)."""
    for alt in fp.config.alternatives:
        if alt.model.kind == label:
            return alt
    if label == Sphere.kind:
        return ParticleConfig(Sphere(0.5, 1.5))
    raise KeyError(f"static.json gives a track the model {label!r}, which the run does not "
                   "name (give it with -p)")


def _left_out_rows(fp: FitPasses, statics: dict[int, TrackStatic]) -> pd.DataFrame:
    """``skipped`` rows, saying why, for every frame of the tracks the initial pass left
    out."""
    rows: list[dict[str, Any]] = []
    for p, s in statics.items():
        if s.fitted:
            continue
        reason = str(s.doc.get("reason") or s.status)
        for k in fp.keys_of(p):
            rows.append({"particle": p, "frame": k[1], "model": s.model, "status": SKIPPED,
                         "message": f"track {p} left out ({s.status}): {reason}"})
    return pd.DataFrame(rows)


def _sweeps(fp: FitPasses, cfg: Any, table: pd.DataFrame, meta: dict[str, Any],
            key: str) -> pd.DataFrame:
    """The continuity sweeps on the followed tracks' rows (their frames refitted from the
    neighbours'); the others as they are."""
    c = fp.config
    mine = table["model"] == fp.particle.model.kind
    run = SweepRun(cfg, partial(load_payload, fp.loader), fp.batch, fp.out / "continuity", meta,
                   key)
    swept, reports = continuity_sweeps(table[mine], run, c.continuity, c.outlier_factor)
    fp.run.continuity = reports.get(fp.tracks[0]) if len(reports) == 1 else None
    fp.run.continuity_by_track = reports
    meta["continuity"] = {"settings": c.continuity.__dict__,
                          "tracks": {str(p): r.as_dict() for p, r in reports.items()}}
    if len(reports) == 1:
        meta["continuity"].update(next(iter(reports.values())).as_dict())
    out = pd.concat([swept, table[~mine]], ignore_index=True)
    return out.sort_values(["particle", "frame"]).reset_index(drop=True)[list(table.columns)]


def _continuity_from(fp: FitPasses, path: Path) -> None:
    """The sweeps' reports recorded in a complete final table's sidecar."""
    doc = json.loads(sidecar_path(path).read_text()).get("continuity")
    if not isinstance(doc, dict):
        return
    fields = ContinuityReport.__dataclass_fields__
    reports = {int(p): ContinuityReport(**{k: v for k, v in r.items() if k in fields})
               for p, r in (doc.get("tracks") or {}).items()}
    fp.run.continuity_by_track = reports
    fp.run.continuity = reports.get(fp.tracks[0]) if len(reports) == 1 else None


def _write_tracks(fp: FitPasses, statics: dict[int, TrackStatic], path: Path) -> None:
    """``tracks.csv`` with each track's final-pass counts."""
    table = read_table(path)
    counts = {int(p): rows["status"].value_counts().to_dict()
              for p, rows in table.groupby("particle")}
    initial = fp.out / "initial.csv"
    initial_frames: dict[int, tuple[int, ...]] = {}
    if initial.exists():
        first = read_table(initial)
        initial_frames = {int(p): tuple(int(f) for f in rows["frame"])
                          for p, rows in first.groupby("particle")}
    outcomes = []
    for p, s in statics.items():
        status = s.status if s.status in ("fitted", "left_out", "unmodelled") else "left_out"
        reason = str(s.doc.get("model_test", {}).get("reason", "") or s.doc.get("reason", ""))
        outcomes.append(TrackOutcome(p, s.model, status, reason, str(s.doc.get("remedy", "")),
                                     initial_frames.get(p, ()), statics=dict(s.values)))
        if not s.fitted:
            fp.run.left_out[p] = reason
    fp.run.tracks = write_tracks(fp.out / "tracks.csv", outcomes, counts, inputs=[path])
