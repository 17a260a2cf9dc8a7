"""What the fit stage's passes share: their inputs and settings, and their batches.

Each pass (:mod:`holofit.fit.initial_pass`, :mod:`holofit.fit.final_pass`) is a batch of the
stage skeleton (:mod:`holofit.batch.stage`) whose items are keyed by ``(particle, frame)``
(independent frames, :meth:`FitPasses.frame_pass`: ``<stem>_frames.csv``) or ``(particle,
chunk, frame)`` (a pass that follows the tracks, :meth:`FitPasses.followed_pass`:
``<stem>_chunks.csv``), then steps on the whole table in this process, then the pass's table
published atomically under its own name (``initial.csv``, ``fit.csv``), the last file
written. A published table whose fingerprint matches is complete: a rerun does nothing more.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from functools import partial
from pathlib import Path
from typing import Any, cast

import pandas as pd

from holofit.batch.options import BatchSettings, Precomputed, available_cpus
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
    INITIAL_OVERLAP,
    MIN_CHUNK,
    OVERLAP,
    consecutive_runs,
    initial_min_chunk,
    plan_chunks,
    stitch_table,
)
from holofit.fit.config import FitConfig, FitRun
from holofit.fit.follow import FOLLOW_COLUMNS
from holofit.fit.overlaps import Neighbours, refit_overlaps
from holofit.fit.task import (
    FitPayload,
    PassConfig,
    TrackSetup,
    fit_frame_task,
    pass_columns,
)
from holofit.io.tables import read_table, write_table
from holofit.library.search import Candidate
from holofit.quality import outlier_rule, outlier_sidecar
from holofit.status import FIT_STATUS_MEANINGS, describe
from holofit.tables.cropset import PARTICLE_KEY
from holofit.tables.fit import fit_table_meta

__all__ = ["INITIAL_STOP_CHI2", "FitPasses", "load_payload", "table_digest"]

#: the initial pass's fits stop where the Gauss-Newton step predicts a chi^2 decrease of at
#: most this (:attr:`holofit.fit.settings.FrameFitSettings.stop_chi2`): one frame's static
#: parameters scatter from the movie's median by far more than a chi^2 unit means, and the
#: median over the frames is what the final pass uses
INITIAL_STOP_CHI2 = 1.0


def load_payload(loader: FrameLoader, key: Any) -> FitPayload | Precomputed:
    """The shared loader's item as the fit's payload."""
    got = loader(key)
    if isinstance(got, Precomputed):
        return got
    return FitPayload(got.crop, got.corner, got.start,
                      tuple(Candidate(*c) for c in got.candidates))  # type: ignore[arg-type]


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
    batch : BatchSettings, optional
        Backend and resumption.
    """

    given: StageInputs
    config: FitConfig
    particle: ParticleConfig
    loader: FrameLoader
    inputs: list[Path]
    out: Path
    run: FitRun
    batch: BatchSettings | None = None

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
        columns = pass_columns(cfg)
        return fit_table_meta(
            columns, kind=f"DDA fit table ({cfg.pass_name} pass)", config=cfg.as_dict(),
            inputs=list[str | Path](self.inputs), status_unit=describe(FIT_STATUS_MEANINGS),
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

    # -- batches ----------------------------------------------------------------------------
    def frame_pass(self, cfg: PassConfig, keys: Sequence[tuple[int, int]],
                   stem: str | None = None) -> tuple[pd.DataFrame, str, dict[str, Any]]:
        """A pass of independent frames through the stage skeleton (``<stem>_frames.csv``;
        default stem: the pass's table's); its table, fingerprint and (no) sidecar entries."""
        stem = stem or ("initial" if cfg.pass_name == "initial" else "fit")
        key = self.batch_key(cfg)
        table = StageTable(self.out / f"{stem}_frames.csv", pass_columns(cfg),
                           self.meta(cfg), key, f"fit ({stem.replace('_', ' ')})",
                           finish=self.finish_rule(cfg), key_columns=PARTICLE_KEY)
        self.run.summaries[stem if stem not in ("initial", "fit") else cfg.pass_name], _ = (
            run_stage(fit_frame_task, cfg, keys, partial(load_payload, self.loader), table,
                      batch=self.batch))
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
        dear: dict[str, Any] = {"pole_probes": 0, "recheck_rad": 0.0, "reopen_dz_um": ()}
        follow = replace(c.follow, frame=cfg.options, **({} if name == "final" else dear))
        ccfg = ChunkConfig(cfg, follow, tuple((p, b) for p, (b, _) in sorted(bars.items())),
                           OVERLAP if name == "final" else INITIAL_OVERLAP)
        base = pass_columns(cfg)
        columns = (*base[:-3], *FOLLOW_COLUMNS, *base[-3:])
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
        # a multi-row item (a chunk's rows: the batch loop writes a list row by row), which
        # run_stage's annotation of the item function (one row) does not say
        chunk_func = cast(Callable[[Any, Any, Any], dict[str, Any]], follow_chunk_task)
        self.run.summaries[name], _ = run_stage(
            chunk_func, ccfg, items,
            chunk_loader(self.loader, chunks, self.given.instrument.frame_rate_hz, poses),
            chunk_table, batch=self.batch,
            sizes={(p, i, ch[0]): len(ch) for p, cs in chunks.items()
                   for i, ch in enumerate(cs)})
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
        given (its lattice fixed), each track's model and statics (no T-matrix)."""
        cfg = PassConfig(self.particle, self.given.instrument, name, self.config.frame,
                         self.config.engine, self.config.fixed, fit_na=self.config.fit_na)
        if setups:
            cfg = cfg.with_tracks({p: replace(s, tmatrix=None) for p, s in setups.items()})
        return cfg

    def refit_overlaps(self, table: pd.DataFrame, cfg: PassConfig, name: str, stem: str,
                       neighbours: Neighbours | None = None) -> pd.DataFrame:
        """A pass's overlapping rows refitted with their neighbour's field (the batch's table
        ``overlaps/<stem>.csv``; the neighbours' fields from ``neighbours`` if given)."""
        out = self.out / "overlaps" / f"{stem}.csv"
        table, n_refit, n_ok, summary = refit_overlaps(table, self.given.crops, cfg, out,
                                                       self.batch, neighbours)
        if summary is not None:
            self.run.summaries[f"{name}, overlaps"] = summary
            self.run.notes.append(f"{name} pass: overlapping frames refitted with the "
                                  f"neighbour's field: {n_refit} ({n_ok} ok)")
        return table

    def pictures(self, path: Path, cfg: PassConfig, name: str, stem: str) -> None:
        """The pass's parameter plots and a few frames' data / model / residual pictures."""
        if self.config.plot:
            from holofit.fit.pictures import pass_pictures

            pass_pictures(path, self.given, cfg, self.out, name, stem, self.config)

