"""The initial pass: every parameter free on some frames of each track, with each model of the
run; each track's model and static parameters (``static.json``) and what became of it
(``tracks.csv``).

1. The primary model's pass (``initial.csv``): a particle with a T-matrix has each track's
   frames spread over the movie, each seeded from the start statics' T-matrix
   (:mod:`holofit.fit.seeded`); without one the pass follows each track from its first frames;
   with independent frames (or a sphere) the first frames are fitted each from the library.
2. Each alternative model (:mod:`holofit.fit.models`) on the same frames, independently
   (``initial_<model>.csv``).
3. Per track: its rows clearly worse than its best quarter flagged
   (:func:`holofit.quality.flag_off_level`), overlapping rows refitted with the neighbour's
   field (:mod:`holofit.fit.overlaps`), the model of the lowest BIC chosen
   (:func:`holofit.fit.models.choose_model`), its statics averaged (:mod:`holofit.fit.static`);
   a track without an ``ok`` row under its model is left out, with the cause and the remedy
   (:mod:`holofit.fit.track_status`), and the others go on.
"""

from __future__ import annotations

import math
from functools import partial
from pathlib import Path
from typing import Any

import pandas as pd

from holofit.batch.layout import publish_table, published_fingerprint
from holofit.batch.stage import fingerprint
from holofit.config import ParticleConfig
from holofit.fit.defaults import INITIAL_MAX, INITIAL_MIN, INITIAL_SHARE, default_initial_frames
from holofit.fit.errors import FitStageError
from holofit.fit.models import ModelFits, choose_model, parameter_count, prefit_sphere
from holofit.fit.overlaps import Neighbours, overlap_rows
from holofit.fit.passes import FitPasses, table_digest
from holofit.fit.pictures import picture_prefix
from holofit.fit.seeded import SEED_BUILD, seed_particle
from holofit.fit.static import static_average, write_static
from holofit.fit.task import PassConfig, TrackSetup
from holofit.fit.tmatrix_policy import final_tmatrix
from holofit.fit.track_status import TrackOutcome, left_out, write_tracks
from holofit.holomodel.parameters import static_values
from holofit.io.tables import read_table
from holofit.particles import Sphere
from holofit.quality import flag_off_level, initial_level, per_track
from holofit.status import FITTABLE_CROP_STATUSES, OK
from holofit.tables.crop import merge_suspects

__all__ = ["INITIAL_PRECISION", "flag_initial", "initial_choice",
           "initial_particle", "initial_pass"]

#: the precision of the initial pass's DDA solves where the particle's ``[dda]`` table does not
#: choose one (:func:`initial_particle`)
INITIAL_PRECISION = "single"


def initial_particle(particle: ParticleConfig) -> ParticleConfig:
    """The particle config of the initial pass: its direct DDA solves use the single-precision
    FFT convolution (:data:`INITIAL_PRECISION`) unless the ``[dda]`` table sets
    ``precision``: the solver's tolerance (1e-5), not the convolution's precision (~1e-7), sets
    the model's and the finite differences' precision. A particle without a ``[dda]`` table is
    returned as it is."""
    dda = particle.settings.get("dda")
    if not isinstance(dda, dict) or "precision" in dda:
        return particle
    return ParticleConfig(particle.model, {**particle.settings,
                                           "dda": {**dda, "precision": INITIAL_PRECISION}},
                          particle.path)


def initial_choice(fittable: list[int], overlapped: list[bool], n: int,
                   spread: bool = False, distance: list[float] | None = None,
                   suspect: list[bool] | None = None) -> list[int]:
    """A track's initial frames: ``n`` of ``fittable`` whose crop no other track's hologram
    overlaps, then (too few of those) overlapped ones, those whose nearest neighbour is
    farthest first (``distance``; else in frame order), then frames suspected of holding a
    merged neighbour (``suspect``: :func:`holofit.tables.crop.merge_suspects`); in frame
    order. The static parameters are best measured on a particle alone, and a merged pair
    looks alone.

    ``spread``: evenly spaced over the clean frames (the middle one of each of ``n`` equal
    runs; overlapped ones: over the farther half), for frames fitted each on its own: the
    statics need orientations; else the first ``n``, for a pass that follows the track from
    frame to frame."""
    doubt = suspect if suspect is not None else [False] * len(fittable)
    far = distance if distance is not None else [0.0] * len(fittable)
    rows = list(zip(fittable, overlapped, doubt, far, strict=True))
    clean = [f for f, o, d, _ in rows if not o and not d]
    near = [f for f, o, d, _ in sorted((r for r in rows if r[1] and not r[2]),
                                       key=lambda r: -r[3])]
    doubtful = [f for f, _, d, _ in rows if d]
    if spread and n < len(clean):
        clean = _spread(clean, n)
    need = n - len(clean)
    if spread and 0 < need < len(near):
        # the farther half (at least ``need``), spread over the movie
        near = _spread(sorted(near[:max(need, len(near) // 2)]), need)
    return sorted((clean + near + doubtful)[:n])


def _spread(frames: list[int], n: int) -> list[int]:
    """``n`` of ``frames`` (``n < len(frames)``): the middle one of each of ``n`` equal runs."""
    return [frames[(2 * i + 1) * len(frames) // (2 * n)] for i in range(n)]


def flag_initial(table: pd.DataFrame, sigmas: float) -> dict[str, Any] | None:
    """Each track's initial rows clearly worse than its best quarter become ``poor_fit``
    (:func:`holofit.quality.flag_off_level`, in place); the sidecar's ``initial_level`` entry
    (None: nothing flagged)."""
    levels = {str(p): initial_level(rows, sigmas) for p, rows in table.groupby("particle")}
    flagged = per_track(partial(flag_off_level, sigmas=sigmas))(table)
    if not flagged:
        return None
    doc: dict[str, Any] = {"sigmas": sigmas, "flagged": flagged,
                           "rule": "ok rows above their track's best quarter's level become "
                                   "poor_fit (holofit.quality.flag_off_level)"}
    if len(levels) == 1:
        doc["chi2_red"] = next(iter(levels.values()))
    else:
        doc["chi2_red_by_track"] = levels
    return doc


def _neighbour_px(crop_row: dict[str, Any]) -> float:
    """The crop table's distance to the nearest other track, px (inf: none; 0: unknown)."""
    try:
        value = float(crop_row.get("neighbour_px", 0.0))
    except (TypeError, ValueError):
        return 0.0
    return 0.0 if math.isnan(value) else value


def _overlapped(crop_row: dict[str, Any]) -> bool:
    """Whether the crop table marks this crop as overlapped by another track's hologram."""
    return str(crop_row.get("overlap", "")).strip().lower() in ("true", "1")


def initial_pass(fp: FitPasses) -> Path:
    """The initial pass (module docstring); the path of ``static.json``.

    Raises
    ------
    FitStageError
        No track has an ``ok`` initial row (the message says why of each).
    """
    c = fp.config
    particle = initial_particle(fp.particle)
    fittable = {p: [k[1] for k in fp.keys_of(p)
                    if fp.given.crops.row(k).get("status") in FITTABLE_CROP_STATUSES]
                for p in fp.tracks}
    followed = c.follow.warm and c.follow.initial and particle.model.anisotropic
    seed = None
    if followed:
        seeding = final_tmatrix(seed_particle(particle), fp.given.instrument, c.engine,
                                c.tmatrix, max(map(len, fittable.values()), default=0), fp.out,
                                fp.local_workers(), name="tmatrix_start.npz",
                                purpose="initial pass's poses (start statics)",
                                build_options=SEED_BUILD)
        if seeding.path is not None:
            seed = str(seeding.path)
            fp.run.notes += seeding.notes
    chosen = _initial_keys(fp, fittable, spread=seed is not None)
    cfg = fp.pass_config("initial", particle, seed_tmatrix=seed)
    if seed is None and followed:
        table, key, extra = fp.followed_pass(cfg, chosen)
    else:
        table, key, extra = fp.frame_pass(cfg, chosen)
    path = fp.out / "initial.csv"
    fp.run.initial = _finish(fp, table, cfg, key, extra, path)
    primary = read_table(path)
    fits = [ModelFits(particle.model.kind, primary, parameter_count(particle.model, cfg.free))]
    # another model's overlapping rows are refitted with the neighbours' fields of the
    # primary model, the run's own (it describes a sphere as well as a sphere does, where a
    # sphere leaves a rod's rings in the crop)
    neighbours = Neighbours(fp.overlap_config("initial", dict(cfg.tracks) or None), primary)
    for alt, alt_cfg in _alternatives(fp, chosen):
        stem = f"initial_{alt.model.kind}"
        alt_table, alt_key, _ = fp.frame_pass(alt_cfg, chosen, stem)
        alt_path = _finish(fp, alt_table, alt_cfg, alt_key, {}, fp.out / f"{stem}.csv",
                           neighbours)
        fits.append(ModelFits(alt.model.kind, read_table(alt_path),
                              parameter_count(alt.model, alt_cfg.free)))
    fp.pictures(path, cfg, "initial", "initial")
    return _statics(fp, fits, [path, *(fp.out / f"initial_{f.label}.csv" for f in fits[1:])])


def _finish(fp: FitPasses, table: pd.DataFrame, cfg: PassConfig, key: str,
            extra: dict[str, Any], path: Path, neighbours: Neighbours | None = None) -> Path:
    """A model's initial table: each track's off-level rows flagged, overlapping rows refitted
    (with the neighbours' fields of ``neighbours`` if given), published (unless complete
    before this run)."""
    c = fp.config
    key = fingerprint({"batch": key, "rows": table_digest(table),
                       "sigmas": c.continuity.chi2_sigmas,
                       "overlaps": not overlap_rows(fp.given.crops).empty,
                       "neighbours": (table_digest(neighbours.table) if neighbours is not None
                                      else None)})
    if published_fingerprint(path) == key:
        return path
    level = flag_initial(table, c.continuity.chi2_sigmas)
    meta = fp.meta(cfg)
    if level is not None:
        meta["initial_level"] = level
        fp.run.notes.append(
            f"initial pass ({cfg.particle.model.kind}): {level['flagged']} frame(s) fit clearly "
            f"worse than their track's best quarter of frames (poor_fit in {path.name}): left "
            "out of the static parameters and of the final pass's chi^2 bar")
    overlap_cfg = fp.overlap_config("initial", dict(cfg.tracks) or None)
    if cfg.particle.model.kind != fp.particle.model.kind:
        overlap_cfg = PassConfig(cfg.particle, cfg.instrument, "initial", c.frame, cfg.engine,
                                 c.fixed, fit_na=c.fit_na, tracks=cfg.tracks)
    table = fp.refit_overlaps(table, overlap_cfg, "initial", path.stem, neighbours)
    return publish_table(path, table, {**meta, **extra}, key)


def _alternatives(fp: FitPasses, chosen: list[tuple[int, int]]
                  ) -> list[tuple[ParticleConfig, PassConfig]]:
    """Each alternative model of the run and its initial pass's config: the ones given, or a
    sphere of each track's prefit size for a non-spherical run (``model_test``)."""
    c = fp.config
    out = []
    for alt in c.alternatives:
        out.append((alt, fp.pass_config("initial", alt)))
    if not out and c.model_test and fp.particle.model.anisotropic:
        tracks = sorted({k[0] for k in chosen})
        setups: dict[int, TrackSetup] = {}
        default = Sphere(0.5, 1.5)
        for p in tracks:
            sphere = prefit_sphere(fp.loader.prefit, p) if fp.loader.prefit is not None else None
            s = sphere or default
            index = float(complex(s.index).real)
            setups[p] = TrackSetup((("radius_um", s.radius_um), ("n", index)))
        base = ParticleConfig(default)
        cfg = fp.pass_config("initial", base).with_tracks(setups)
        # the sphere is Lorenz-Mie's whatever engine the run's particle has
        out.append((base, PassConfig(base, cfg.instrument, "initial", cfg.options, "mie",
                                     cfg.fixed, fit_na=cfg.fit_na, tracks=cfg.tracks)))
    return out


def _statics(fp: FitPasses, fits: list[ModelFits], inputs: list[Path]) -> Path:
    """Each track's model and statics into ``static.json``, its fate into ``tracks.csv``."""
    c = fp.config
    models = {fp.particle.model.kind: fp.particle.model,
              **{a.model.kind: a.model for a in c.alternatives}}
    configured = set(models)
    if len(fits) > 1 and fits[1].label not in models:
        models[fits[1].label] = Sphere(0.5, 1.5)
    entries: dict[int, dict[str, Any]] = {}
    outcomes: list[TrackOutcome] = []
    by_label = {f.label: f for f in fits}
    choices = {p: choose_model(fits, p) for p in fp.tracks}
    for p in fp.tracks:
        choice = choices[p]
        rows = by_label[choice.label].table
        rows = rows[rows["particle"] == p]
        model = models[choice.label]
        if not (rows["status"] == OK).any():
            picture = f"frames_initial/{picture_prefix(p, len(fp.tracks))}frame_*.png"
            outcome = left_out(rows, p, choice.label, picture if c.plot else None)
            if len(fits) > 1:
                outcome = TrackOutcome(p, choice.label, "unmodelled",
                                       f"no model of the run fits it: {outcome.reason}",
                                       outcome.remedy, outcome.frames)
            entries[p] = {"model": choice.label, "status": outcome.status,
                          "reason": outcome.reason, "remedy": outcome.remedy}
            outcomes.append(outcome)
            continue
        entry = {"model": choice.label, "status": "fitted", **static_average(rows, model)}
        if choice.label in configured:
            entry["start"] = dict(static_values(model))
        if len(fits) > 1:
            entry["model_test"] = {"bic": choice.bic, "n_frames": choice.n_frames,
                                   "reason": choice.reason}
        entries[p] = entry
        outcomes.append(TrackOutcome(p, choice.label, "fitted", choice.reason,
                                     frames=tuple(int(f) for f in rows["frame"]),
                                     statics=dict(entry["values"])))
    if c.static_mode == "pooled":
        _pool(entries, by_label, models)
    fitted = [o for o in outcomes if o.fitted]
    if not fitted:
        raise FitStageError("no track has an ok initial frame: " + "; ".join(
            f"particle {o.particle}: {o.reason} ({o.remedy})" for o in outcomes))
    for o in outcomes:
        if not o.fitted:
            fp.run.left_out[o.particle] = o.reason
            fp.run.notes.append(f"particle {o.particle} left out: {o.reason}. {o.remedy}")
    if len(fits) > 1:
        chosen = {o.particle: o.model for o in fitted}
        for label in by_label:
            n = sum(1 for m in chosen.values() if m == label)
            if n:
                fp.run.notes.append(f"model test: {n} track(s) fit best as a {label}")
    fp.run.tracks = write_tracks(fp.out / "tracks.csv", outcomes, inputs=inputs)
    return write_static(fp.out / "static.json", inputs, entries, fp.particle.model,
                        c.static_mode)


def _pool(entries: dict[int, dict[str, Any]], fits: dict[str, ModelFits],
          models: dict[str, Any]) -> None:
    """``pooled``: every fitted track of a model gets that model's average over all of them."""
    for label, f in fits.items():
        tracks = [p for p, e in entries.items() if e["status"] == "fitted"
                  and e["model"] == label]
        if not tracks:
            continue
        rows = f.table[f.table["particle"].isin(tracks)]
        try:
            pooled = static_average(rows, models[label])
        except FitStageError as exc:
            raise FitStageError(f"pooled static parameters: {exc}") from None
        for p in tracks:
            entries[p] = {**entries[p], **pooled}


def _initial_keys(fp: FitPasses, fittable: dict[int, list[int]], spread: bool
                  ) -> list[tuple[int, int]]:
    """Each track's initial frames (:func:`initial_choice`), said in the notes."""
    crops, n_given = fp.given.crops, fp.config.initial_frames
    suspects = merge_suspects(list(crops.sidecar.get("track_losses") or []))
    keys: list[tuple[int, int]] = []
    for p, frames in fittable.items():
        n = n_given if n_given is not None else default_initial_frames(len(frames))
        rows = [crops.row((p, f)) for f in frames]
        over = [_overlapped(r) for r in rows]
        merged = suspects.get(p, set())
        doubt = [f in merged for f in frames]
        chosen = initial_choice(frames, over, n, spread=spread,
                                distance=[_neighbour_px(r) for r in rows], suspect=doubt)
        taken = set(chosen)
        clean_chosen = sum(not o for f, o in zip(frames, over, strict=True) if f in taken)
        keys += [(p, f) for f in chosen]
        who = "" if len(fittable) == 1 else f"particle {p}: "
        if n_given is None:
            which = (f"{n} of the {len(frames)} frames that can be fitted, spread over the "
                     "movie" if spread else
                     f"the first {n} of the {len(frames)} frames that can be fitted")
            fp.run.notes.append(
                f"{who}initial pass (every parameter free) on {which}: the default, 1 in "
                f"{INITIAL_SHARE}, at least {INITIAL_MIN}, at most {INITIAL_MAX} "
                "(--initial-frames N to choose)")
        n_doubt = sum(f in merged for f in chosen)
        if n_doubt:
            fp.run.notes.append(
                f"{who}initial pass: {n_doubt} of {len(chosen)} frames may hold a merged "
                "neighbour (a track lost or found late within reach: the crop sidecar's "
                "track_losses); no other frames to take")
        elif any(doubt):
            fp.run.notes.append(
                f"{who}initial pass: {sum(doubt)} frame(s) left out that may hold a merged "
                "neighbour (the crop sidecar's track_losses)")
        if any(over if spread else over[:n]):
            fp.run.notes.append(
                f"{who}initial pass: frames without another track's overlapping hologram "
                f"first ({clean_chosen} of "
                f"{len(chosen)})")
    return keys
