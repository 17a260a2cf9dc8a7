"""The two passes of the fit stage over every track of a crop folder.

Each pass is a batch of the stage skeleton (:mod:`holofit.batch.stage`) whose items are keyed
by ``(particle, frame)`` (independent frames, ``<pass>_frames.csv``) or
``(particle, chunk, frame)`` (a pass that follows the tracks, ``<pass>_chunks.csv``), then
steps on the whole table in this process, then the pass's table published atomically under
its own name (``initial.csv``, ``fit.csv``), the last file written:

- **initial**: each track's rows clearly worse than its best quarter flagged
  (:func:`holofit.quality.flag_off_level`), overlapping rows refitted with the neighbour's
  field (:mod:`holofit.fit.overlaps`); then ``static.json`` (:mod:`holofit.fit.static`);
- **final**: (followed) the chunks stitched (:mod:`holofit.fit.chunks`) and each track's
  outliers flagged, the continuity sweeps (:mod:`holofit.fit.sweeps`), the overlap refits,
  overlapping rows still not ``ok`` marked ``overlap``.

A published table whose fingerprint matches is complete: a rerun does nothing more.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Sequence
from dataclasses import dataclass, replace
from functools import partial
from pathlib import Path
from typing import Any

import pandas as pd

from holofit.batch.layout import publish_table, published_fingerprint
from holofit.batch.options import BatchOptions, Precomputed, available_cpus
from holofit.batch.stage import FrameLoader, StageInputs, StageTable, fingerprint, run_stage
from holofit.config import ParticleConfig
from holofit.fit.chunk_task import (
    ChunkConfig,
    chunk_loader,
    final_bars,
    follow_chunk_task,
    initial_check_summary,
    initial_poses,
)
from holofit.fit.chunks import (
    CHUNK_KEY,
    INITIAL_MIN_CHUNK,
    INITIAL_OVERLAP,
    MIN_CHUNK,
    OVERLAP,
    consecutive_runs,
    plan_chunks,
    stitch_table,
)
from holofit.fit.config import FitConfig, FitRun
from holofit.fit.continuity import ContinuityReport
from holofit.fit.defaults import INITIAL_MAX, INITIAL_MIN, INITIAL_SHARE, default_initial_frames
from holofit.fit.follow import FOLLOW_COLUMNS
from holofit.fit.overlaps import mark_overlap, overlap_rows, refit_overlaps
from holofit.fit.seeded import SEED_BUILD, seed_particle
from holofit.fit.static import read_static, static_doc, write_static
from holofit.fit.sweeps import SweepRun, continuity_sweeps
from holofit.fit.task import (
    FitPayload,
    PassConfig,
    TrackSetup,
    fit_columns,
    fit_frame_task,
)
from holofit.fit.tmatrix_policy import final_tmatrix
from holofit.holomodel.parameters import particle_with
from holofit.io.tables import read_table, sidecar_path, write_table
from holofit.library.search import Candidate
from holofit.quality import (
    flag_off_level,
    initial_level,
    outlier_rule,
    outlier_sidecar,
    per_track,
)
from holofit.status import FIT_STATUS_MEANINGS, FITTABLE_CROP_STATUSES, describe
from holofit.tables.cropset import PARTICLE_KEY
from holofit.tables.fit import fit_table_meta

__all__ = [
    "INITIAL_PRECISION",
    "INITIAL_STOP_CHI2",
    "FitPasses",
    "flag_initial",
    "initial_choice",
    "initial_min_chunk",
    "initial_particle",
    "load_payload",
]

#: the precision of the initial pass's DDA solves where the particle's ``[dda]`` table does not
#: choose one (:func:`initial_particle`)
INITIAL_PRECISION = "single"
#: the initial pass's fits stop where the Gauss-Newton step predicts a chi^2 decrease of at
#: most this (:attr:`holofit.fit.settings.FrameFitSettings.stop_chi2`): one frame's static
#: parameters scatter from the movie's median by far more than a chi^2 unit means, and the
#: median over the frames is what the final pass uses
INITIAL_STOP_CHI2 = 1.0


def initial_particle(particle: ParticleConfig) -> ParticleConfig:
    """The particle config of the initial pass: its direct DDA solves use the single-precision
    FFT convolution (:data:`INITIAL_PRECISION`) unless the ``[dda]`` table sets
    ``precision``: the solver's tolerance (1e-5), not the convolution's precision (~1e-7), sets
    the model's and the finite differences' precision. A particle without a ``[dda]`` table is
    returned as it is."""
    dda = particle.settings.get("dda")
    if not isinstance(dda, dict) or "precision" in dda:
        return particle
    return replace(particle, settings={**particle.settings,
                                       "dda": {**dda, "precision": INITIAL_PRECISION}})


def initial_choice(fittable: list[int], overlapped: list[bool], n: int,
                   spread: bool = False) -> list[int]:
    """A track's initial frames: ``n`` of ``fittable`` whose crop no other track's hologram
    overlaps, then (too few of those) the first overlapped ones; in frame order. The static
    parameters are best measured on a particle alone.

    ``spread``: evenly spaced over the clean frames (the middle one of each of ``n`` equal
    runs), for frames fitted each on its own: the statics need orientations; else the first
    ``n``, for a pass that follows the track from frame to frame."""
    clean = [f for f, o in zip(fittable, overlapped, strict=True) if not o]
    rest = [f for f, o in zip(fittable, overlapped, strict=True) if o]
    if spread and n < len(clean):
        clean = [clean[(2 * i + 1) * len(clean) // (2 * n)] for i in range(n)]
    return sorted((clean + rest)[:n])


def initial_min_chunk(n_frames: int) -> int:
    """The initial pass's shortest chunk for ``n_frames`` frames: a short initial pass is
    still cut in two, one chunk per worker of a 2-core machine."""
    if n_frames >= 2 * INITIAL_MIN_CHUNK:
        return INITIAL_MIN_CHUNK
    return max(n_frames // 2, 2)


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


def load_payload(loader: FrameLoader, key: Any) -> FitPayload | Precomputed:
    """The shared loader's item as the fit's payload."""
    got = loader(key)
    if isinstance(got, Precomputed):
        return got
    return FitPayload(got.crop, got.corner, got.start,
                      tuple(Candidate(*c) for c in got.candidates))  # type: ignore[arg-type]


def _overlapped(crop_row: dict[str, Any]) -> bool:
    """Whether the crop table marks this crop as overlapped by another track's hologram."""
    return str(crop_row.get("overlap", "")).strip().lower() in ("true", "1")


def table_digest(table: pd.DataFrame) -> str:
    """The identity of a pass's rows (the table a published one is derived from)."""
    return hashlib.sha256(pd.util.hash_pandas_object(table, index=False).to_numpy()
                          .tobytes()).hexdigest()[:16]


@dataclass
class FitPasses:
    """The passes of one :func:`holofit.fit.stage.run_fit`: their shared inputs and settings.

    Attributes
    ----------
    given : StageInputs
        The crops, instrument and ``(particle, frame)`` keys.
    config : FitConfig
        The stage's configuration.
    particle : ParticleConfig
        The particle, its lattice fixed for both passes.
    loader : FrameLoader
        The crops with the prefit's and the library's rows.
    inputs : list of Path
        The tables read (the sidecars name them).
    out : Path
        The output folder.
    run : FitRun
        What the stage wrote, filled in.
    batch : BatchOptions, optional
        Backend and resumption.
    """

    given: StageInputs
    config: FitConfig
    particle: ParticleConfig
    loader: FrameLoader
    inputs: list[Path]
    out: Path
    run: FitRun
    batch: BatchOptions | None = None

    # -- shared ---------------------------------------------------------------------------
    @property
    def tracks(self) -> list[int]:
        return sorted({int(k[0]) for k in self.given.frames})

    def keys_of(self, particle: int) -> list[tuple[int, int]]:
        return [k for k in self.given.frames if int(k[0]) == particle]

    def local_workers(self) -> int:
        """Processes of this machine the stage may use, for work in the driver (a T-matrix
        build)."""
        workers = self.batch.workers if self.batch is not None else None
        return available_cpus() if workers is None else max(workers, 1)

    def pass_config(self, name: str, particle: ParticleConfig, **kw: Any) -> PassConfig:
        """A pass's worker config: the initial pass's fits stop within
        :data:`INITIAL_STOP_CHI2` of their minimum unless the settings ask for more."""
        c = self.config
        opts = c.frame
        if name == "initial":
            opts = replace(opts, stop_chi2=max(opts.stop_chi2, INITIAL_STOP_CHI2))
        return PassConfig(particle, self.given.instrument, name, opts, c.engine, c.fixed,
                          fit_na=c.fit_na, **kw)

    def meta(self, cfg: PassConfig, static: dict[str, Any] | None = None) -> dict[str, Any]:
        """A pass table's sidecar (the fit-table schema's)."""
        inst, model = self.given.instrument, cfg.particle.model
        columns = fit_columns(model, cfg.free)
        return fit_table_meta(
            columns, kind=f"DDA fit table ({cfg.pass_name} pass)", config=cfg.as_dict(),
            inputs=self.inputs, status_unit=describe(FIT_STATUS_MEANINGS),
            frame_interval_s=1.0 / inst.frame_rate_hz if inst.frame_rate_hz else None,
            extra={"crops": self.given.crops.fingerprint(), "particle_model": model.kind,
                   "quality": outlier_sidecar(self.config.outlier_factor,
                                              self.probability(cfg)),
                   **({"static": static} if static else {})})

    def probability(self, cfg: PassConfig) -> float | None:
        """The improbable-chi^2 rule's probability for a pass's table: the final pass's
        (:func:`holofit.quality.flag_improbable`); the initial pass's rows fit their own
        statics and are judged by their level instead."""
        return self.config.continuity.flag_probability if cfg.pass_name == "final" else None

    def finish_rule(self, cfg: PassConfig) -> Any:
        """The rules a pass's complete table is finished with (:mod:`holofit.quality`)."""
        return outlier_rule(self.config.outlier_factor, self.probability(cfg))

    def batch_key(self, cfg: PassConfig, **extra: Any) -> str:
        return fingerprint({"config": cfg.as_dict(), "crops": self.given.crops.fingerprint(),
                            "outlier_factor": self.config.outlier_factor,
                            "flag_probability": self.probability(cfg), **extra})

    # -- the initial pass -----------------------------------------------------------------
    def initial(self) -> Path:
        """The initial pass; writes ``initial.csv`` and ``static.json``, whose path it
        returns. A particle with a T-matrix has each track's frames spread over the movie,
        each seeded from the start statics' T-matrix (:mod:`holofit.fit.seeded`); without one
        the pass follows each track from its first frames; with independent frames (or a
        sphere) the first frames are fitted each from the library."""
        crops, c = self.given.crops, self.config
        particle = initial_particle(self.particle)
        model = particle.model
        fittable = {p: [k[1] for k in self.keys_of(p)
                        if crops.row(k).get("status") in FITTABLE_CROP_STATUSES]
                    for p in self.tracks}
        followed = c.follow.warm and c.follow.initial and model.anisotropic
        seed = None
        if followed:
            seeding = final_tmatrix(seed_particle(particle), self.given.instrument, c.engine,
                                    c.tmatrix, max(map(len, fittable.values()), default=0),
                                    self.out, self.local_workers(), name="tmatrix_start.npz",
                                    purpose="initial pass's poses (start statics)",
                                    build_options=SEED_BUILD)
            if seeding.path is not None:
                seed = str(seeding.path)
                self.run.notes += seeding.notes
        chosen = self._initial_keys(fittable, spread=seed is not None)
        cfg = self.pass_config("initial", particle, seed_tmatrix=seed)
        if seed is None and followed:
            table, key, extra = self.followed_pass(cfg, chosen)
        else:
            table, key, extra = self.frame_pass(cfg, chosen)
        path = self.out / "initial.csv"
        key = fingerprint({"batch": key, "rows": table_digest(table),
                           "sigmas": c.continuity.chi2_sigmas,
                           "overlaps": not overlap_rows(crops).empty})
        if published_fingerprint(path) != key:
            level = flag_initial(table, c.continuity.chi2_sigmas)
            meta = self.meta(cfg)
            if level is not None:
                meta["initial_level"] = level
                self.run.notes.append(
                    f"initial pass: {level['flagged']} frame(s) fit clearly worse than their "
                    "track's best quarter of frames (poor_fit in initial.csv): left out of the "
                    "static parameters and of the final pass's chi^2 bar")
            table = self._refit_overlaps(table, self.overlap_config("initial"), "initial")
            publish_table(path, table, {**meta, **extra}, key)
        self.run.initial = path
        self._pictures(path, cfg, "initial", "initial")
        return write_static(self.out / "static.json", path, read_table(path), self.particle.model,
                            c.static_mode)

    def _initial_keys(self, fittable: dict[int, list[int]], spread: bool
                      ) -> list[tuple[int, int]]:
        """Each track's initial frames (:func:`initial_choice`), said in the notes."""
        crops, n_given = self.given.crops, self.config.initial_frames
        keys: list[tuple[int, int]] = []
        for p, frames in fittable.items():
            n = n_given if n_given is not None else default_initial_frames(len(frames))
            over = [_overlapped(crops.row((p, f))) for f in frames]
            chosen = initial_choice(frames, over, n, spread=spread)
            keys += [(p, f) for f in chosen]
            who = "" if len(fittable) == 1 else f"particle {p}: "
            if n_given is None:
                which = (f"{n} of the {len(frames)} frames that can be fitted, spread over the "
                         "movie" if spread else
                         f"the first {n} of the {len(frames)} frames that can be fitted")
                self.run.notes.append(
                    f"{who}initial pass (every parameter free) on {which}: the default, 1 in "
                    f"{INITIAL_SHARE}, at least {INITIAL_MIN}, at most {INITIAL_MAX} "
                    "(--initial-frames N to choose)")
            if any(over if spread else over[:n]):
                self.run.notes.append(
                    f"{who}initial pass: frames without another track's overlapping hologram "
                    f"first ({sum(not _overlapped(crops.row((p, f))) for f in chosen)} of "
                    f"{len(chosen)})")
        return keys

    # -- the final pass -------------------------------------------------------------------
    def final(self, static_path: Path) -> None:
        """The final pass on every frame, each track's static parameters fixed to
        ``static_path``'s."""
        c, model = self.config, self.particle.model
        setups: dict[int, TrackSetup] = {}
        statics: dict[int, dict[str, float]] = {
            p: read_static(static_path, model, p) for p in self.tracks}
        built: dict[tuple[tuple[str, float], ...], str | None] = {}
        shared = len({tuple(sorted(v.items())) for v in statics.values()}) <= 1
        for p in self.tracks:
            values = tuple(sorted(statics[p].items()))
            if values not in built:
                settled = ParticleConfig(particle_with(model, dict(values)),
                                         self.particle.settings, self.particle.path)
                name = "tmatrix.npz" if shared else f"tmatrix_p{p}.npz"
                tm = final_tmatrix(settled, self.given.instrument, c.engine, c.tmatrix,
                                   len(self.keys_of(p)), self.out, self.local_workers(),
                                   name=name)
                self.run.notes += tm.notes
                if tm.path is not None:
                    self.run.tmatrix = tm.path
                    self.run.tmatrix_s += tm.seconds
                built[values] = None if tm.path is None else str(tm.path)
            setups[p] = TrackSetup(values, built[values])
        first = setups[self.tracks[0]] if self.tracks else TrackSetup()
        base = ParticleConfig(particle_with(model, dict(first.statics)), self.particle.settings,
                              self.particle.path)
        cfg = self.pass_config("final", base, tmatrix=first.tmatrix).with_tracks(setups)
        docs = {str(p): static_doc(static_path, p) for p in self.tracks}
        static = docs[str(self.tracks[0])] if len(docs) == 1 else {"tracks": docs}
        if c.follow.warm and model.anisotropic:
            table, key, extra = self.followed_pass(cfg, list(self.given.frames))
        else:
            table, key, extra = self.frame_pass(cfg, list(self.given.frames))
        path = self.out / "fit.csv"
        key = fingerprint({"batch": key, "rows": table_digest(table),
                           "continuity": c.continuity.__dict__,
                           "overlaps": not overlap_rows(self.given.crops).empty})
        if published_fingerprint(path) != key:
            meta = {**self.meta(cfg, static), **extra}
            if c.continuity.enabled and model.anisotropic:
                run = SweepRun(cfg, partial(load_payload, self.loader), self.batch,
                               self.out / "continuity", meta, key)
                table, reports = continuity_sweeps(table, run, c.continuity, c.outlier_factor)
                self.run.continuity = reports.get(self.tracks[0]) if len(reports) == 1 else None
                self.run.continuity_by_track = reports
                meta["continuity"] = {"settings": c.continuity.__dict__,
                                      "tracks": {str(p): r.as_dict()
                                                 for p, r in reports.items()}}
                if len(reports) == 1:
                    meta["continuity"].update(next(iter(reports.values())).as_dict())
            table = self._refit_overlaps(table, self.overlap_config("final", setups), "final")
            table = mark_overlap(table, overlap_rows(self.given.crops))
            publish_table(path, table, meta, key)
        else:  # complete before this run: what the sweeps did, from its sidecar
            self._continuity_from(path)
        self.run.final = path
        self._pictures(path, cfg, "final", "fit")

    def _continuity_from(self, path: Path) -> None:
        """The sweeps' reports recorded in a complete final table's sidecar."""
        doc = json.loads(sidecar_path(path).read_text()).get("continuity")
        if not isinstance(doc, dict):
            return
        fields = ContinuityReport.__dataclass_fields__
        reports = {int(p): ContinuityReport(**{k: v for k, v in r.items() if k in fields})
                   for p, r in (doc.get("tracks") or {}).items()}
        self.run.continuity_by_track = reports
        self.run.continuity = reports.get(self.tracks[0]) if len(reports) == 1 else None

    # -- batches ----------------------------------------------------------------------------
    def frame_pass(self, cfg: PassConfig, keys: Sequence[tuple[int, int]]
                   ) -> tuple[pd.DataFrame, str, dict[str, Any]]:
        """A pass of independent frames through the stage skeleton
        (``<stem>_frames.csv``); its table, fingerprint and (no) sidecar entries."""
        stem = "initial" if cfg.pass_name == "initial" else "fit"
        key = self.batch_key(cfg)
        table = StageTable(self.out / f"{stem}_frames.csv", fit_columns(cfg.particle.model,
                                                                           cfg.free),
                           self.meta(cfg), key, f"fit ({cfg.pass_name})",
                           finish=self.finish_rule(cfg),
                           key_columns=PARTICLE_KEY)
        self.run.summaries[cfg.pass_name], _ = run_stage(
            fit_frame_task, cfg, keys, partial(load_payload, self.loader), table,
            batch=self.batch)
        return read_table(table.path), key, {}

    def followed_pass(self, cfg: PassConfig, keys: Sequence[tuple[int, int]]
                      ) -> tuple[pd.DataFrame, str, dict[str, Any]]:
        """A pass that follows each track (:mod:`holofit.fit.chunk_task`): the chunks through
        the stage skeleton into ``<stem>_chunks.csv``, stitched (outliers flagged, the
        overlaps' disagreements in ``<stem>_overlaps.csv``); its table, fingerprint and
        sidecar entries (``follow``: the settings, bars, chunks and what the checks did)."""
        name, c = cfg.pass_name, self.config
        stem = "initial" if name == "initial" else "fit"
        frames = {p: sorted(k[1] for k in keys if k[0] == p) for p in self.tracks}
        frames = {p: f for p, f in frames.items() if f}
        if name == "final":
            bars = final_bars(self.out / "initial.csv", cfg, list(frames), self.loader,
                              c.continuity.chi2_sigmas)
            for p, (_, note) in bars.items():
                self.run.notes.append(note if len(bars) == 1 else f"particle {p}: {note}")
            poses = initial_poses(self.out / "initial.csv")
            chunks = {p: plan_chunks(f, OVERLAP, min_chunk=MIN_CHUNK) for p, f in frames.items()}
        else:
            self.run.notes.append(f"{name} pass along the track: no chi^2 bar yet (warm fits "
                                  "checked by status and step)")
            bars, poses = {}, {}
            chunks = {p: [ch for part in consecutive_runs(f)
                          for ch in plan_chunks(part, INITIAL_OVERLAP,
                                                min_chunk=initial_min_chunk(len(part)))]
                      for p, f in frames.items()}
        # the initial pass's direct solves are too dear for the probes, the recheck and the
        # other heights; its rows are checked by their level instead
        dear = {"pole_probes": 0, "recheck_rad": 0.0, "reopen_dz_um": ()}
        follow = replace(c.follow, frame=cfg.options, **({} if name == "final" else dear))
        ccfg = ChunkConfig(cfg, follow, tuple((p, b) for p, (b, _) in sorted(bars.items())),
                           OVERLAP if name == "final" else INITIAL_OVERLAP)
        columns = (*fit_columns(cfg.particle.model, cfg.free), *FOLLOW_COLUMNS)
        key_doc: dict[str, Any] = {
            "chunked": ccfg.as_dict(), "crops": self.given.crops.fingerprint(),
            "outlier_factor": c.outlier_factor, "flag_probability": self.probability(cfg),
            "keys": [list(k) for k in keys]}
        if name == "final":
            key_doc["initial_poses"] = sorted((list(k), v) for k, v in poses.items())
        key = fingerprint(key_doc)
        meta = {**self.meta(cfg), "follow": {
            **ccfg.as_dict(), "chunks": {str(p): [[ch[0], ch[-1]] for ch in cs]
                                         for p, cs in chunks.items()}}}
        chunk_table = StageTable(self.out / f"{stem}_chunks.csv", (*CHUNK_KEY, *columns[1:]),
                                 meta, key, f"fit ({name}, chunks)", key_columns=CHUNK_KEY)
        items = [(p, i, ch[0]) for p, cs in chunks.items() for i, ch in enumerate(cs)]
        self.run.summaries[name], _ = run_stage(
            follow_chunk_task, ccfg, items,
            chunk_loader(self.loader, chunks, self.given.instrument.frame_rate_hz, poses),
            chunk_table, batch=self.batch)
        longest = max((len(ch) for cs in chunks.values() for ch in cs), default=0)
        self.run.notes.append(f"{name} pass along the track: {len(items)} chunk(s) of up to "
                              f"{longest} frames (the batch's items), overlapping by "
                              f"{ccfg.overlap}")
        table, overlaps = stitch_table(read_table(chunk_table.path), chunks,
                                       cfg.particle.model.head_tail_symmetric)
        write_table(self.out / f"{stem}_overlaps.csv", overlaps)
        if len(overlaps):
            self.run.notes.append(f"{name} pass: {len(overlaps)} overlap frame(s) of the "
                                  f"chunks disagree ({stem}_overlaps.csv)")
        self.finish_rule(cfg)(table)
        follow_doc = dict(meta["follow"])
        notes = {str(p): n for p, (_, n) in bars.items()}
        follow_doc["chi2_bar_note"] = (next(iter(notes.values())) if len(notes) == 1
                                       else notes)
        follow_doc["overlap_disagreements"] = len(overlaps)
        if poses:
            follow_doc["initial_check"], check_note = initial_check_summary(table)
            self.run.notes.append(check_note)
        return table.reindex(columns=list(columns)), key, {"follow": follow_doc}

    # -- overlaps and pictures ------------------------------------------------------------
    def overlap_config(self, name: str, setups: dict[int, TrackSetup] | None = None
                       ) -> PassConfig:
        """The overlap refits' worker config: the stage's frame settings and the particle as
        given (its lattice fixed), each track's statics in the final pass."""
        cfg = PassConfig(self.particle, self.given.instrument, name, self.config.frame,
                         self.config.engine, self.config.fixed, fit_na=self.config.fit_na)
        if setups:
            cfg = cfg.with_tracks({p: TrackSetup(s.statics) for p, s in setups.items()})
        return cfg

    def _refit_overlaps(self, table: pd.DataFrame, cfg: PassConfig, name: str
                        ) -> pd.DataFrame:
        """A pass's overlapping rows refitted with their neighbour's field."""
        out = self.out / "overlaps" / f"{'fit' if name == 'final' else name}.csv"
        table, n_refit, n_ok, summary = refit_overlaps(table, self.given.crops, cfg, out,
                                                       self.batch)
        if summary is not None:
            self.run.summaries[f"{name}, overlaps"] = summary
            self.run.notes.append(f"{name} pass: overlapping frames refitted with the "
                                  f"neighbour's field: {n_refit} ({n_ok} ok)")
        return table

    def _pictures(self, path: Path, cfg: PassConfig, name: str, stem: str) -> None:
        """The pass's parameter plots and a few frames' data / model / residual pictures."""
        if self.config.plot:
            from holofit.fit.pictures import pass_pictures

            pass_pictures(path, self.given, cfg, self.out, name, stem, self.config)

