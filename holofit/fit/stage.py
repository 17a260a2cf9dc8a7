"""``holofit fit``: the DDA fit of every frame (the paper's steps 5-6).

- **Initial pass** (``initial.csv``): every parameter free (position, orientation, alpha and
  the particle's static parameters: a rod's a, b, n; a Janus particle's core radius, cap
  thickness and both indices; a dimer's radii, gap and indices) on ``initial_frames``
  frames: spread over the movie, each seeded from the start statics' T-matrix, where the
  particle has one (:mod:`holofit.fit.seeded`), else the first ones, from the library's
  candidates and the prefit's position (:meth:`_FitPasses.initial`). The
  static parameters' robust average over the ``ok`` frames (median, with the spread as 1.4826
  times the median absolute deviation) goes to ``static.json``.
- **Final pass** (``fit.csv``): the static parameters fixed to those values (or to a
  ``static.json`` given), position, orientation and alpha fitted on every frame. For an
  anisotropic particle it follows the track (:mod:`holofit.fit.tracked`, the algorithm:
  :mod:`holofit.fit.tracking`): each frame fitted from its predecessor's fit, re-acquired from
  the library where that fails; chunks of the track are the batch items
  (``fit_chunks.csv``), stitched into ``fit.csv`` (disagreeing overlaps:
  ``fit_overlaps.csv``); the initial pass follows the track too.
  ``tracking=TrackOptions(warm=False)`` (``--no-tracking``):
  every frame fitted independently from the library's starts.
- **Continuity sweeps** (:mod:`holofit.fit.sweeps`; the rule: :mod:`holofit.fit.continuity`):
  frames of the final pass that look like a wrong local minimum are refitted from their good
  neighbours' orientations (each sweep a batch of its own, ``continuity/sweep_K.csv``,
  resumable); better fits replace their rows in ``fit.csv`` and frames still far from the data
  become ``poor_fit``.

Both passes are two uses of the stage skeleton (:mod:`holofit.batch.stage`: the shared frame
loader and skip policy, the batch runner: parallel, resumable, failures recorded, a worker
keeps its engine and its caches across frames; the frame function: :mod:`holofit.fit.task`),
write the fit-table schema (:mod:`holofit.tables.fit`: ``holofit analyze`` reads ``fit.csv``
as it is), flag the movie's outlier frames, and draw data / model / residual pictures of a few
frames. ``static.json``: :mod:`holofit.fit.static`; the T-matrix policy:
:mod:`holofit.fit.tmatrix_policy`.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field, replace
from functools import partial
from pathlib import Path
from typing import Any

from threadpoolctl import threadpool_limits

from holofit.batch.aperture import FROM_INSTRUMENT, ApertureChoice
from holofit.batch.runner import (
    BatchOptions,
    BatchSummary,
    Precomputed,
    available_cpus,
    partial_path,
)
from holofit.batch.stage import (
    FrameLoader,
    StageInputs,
    StageTable,
    fingerprint,
    run_stage,
    stage_inputs,
)
from holofit.config import Instrument, ParticleConfig
from holofit.fit.continuity import ContinuityReport, ContinuitySettings
from holofit.fit.defaults import (
    INITIAL_MAX,
    INITIAL_MIN,
    INITIAL_SHARE,
    default_initial_frames,
)
from holofit.fit.errors import FitStageError
from holofit.fit.frame import FrameFitSettings
from holofit.fit.initial_level import flag_initial_table
from holofit.fit.seeded import SEED_BUILD, seed_particle
from holofit.fit.static import read_static, static_average, static_doc, write_static
from holofit.fit.sweeps import continuity_sweeps
from holofit.fit.task import (
    FitConfig,
    FitPayload,
    _free,
    check_fixed,
    fit_columns,
    fit_frame_task,
    fixable_names,
)
from holofit.fit.tmatrix_policy import TMATRIX_CHOICES, check_policy, final_tmatrix
from holofit.fit.tracked import (
    CHUNK_KEY,
    INITIAL_MIN_CHUNK,
    INITIAL_OVERLAP,
    MIN_CHUNK,
    OVERLAP,
    TrackedConfig,
    chunk_loader,
    consecutive_runs,
    final_bar,
    initial_check_summary,
    initial_poses,
    plan_chunks,
    stitch_table,
    track_chunk_task,
)
from holofit.fit.tracking import TRACK_COLUMNS, TrackOptions
from holofit.holomodel.finish import outlier_rule, outlier_sidecar
from holofit.holomodel.parameters import particle_with, static_parameters
from holofit.holomodel.pictures import write_frame_pictures
from holofit.io.tables import read_table, sidecar_path, write_table
from holofit.library.search import Candidate
from holofit.particles import ParticleModel
from holofit.scattering.theory import ScatteringTheory
from holofit.status import FIT_STATUS_MEANINGS, FITTABLE_CROP_STATUSES, describe
from holofit.tables.cropset import CropSet
from holofit.tables.fit import fit_table_meta
from holofit.tables.inputs import StageInputError, read_stage_table

__all__ = [
    "PASSES",
    "TMATRIX_CHOICES",
    "FitConfig",
    "FitPayload",
    "FitRun",
    "FitStageError",
    "_free",
    "check_fixed",
    "default_initial_frames",
    "fit_columns",
    "fit_frame_task",
    "fixable_names",
    "read_static",
    "run_fit",
    "static_average",
]

PASSES = ("initial", "final", "both")


@dataclass
class FitRun:
    """What :func:`run_fit` wrote."""

    initial: Path | None = None
    static: Path | None = None
    final: Path | None = None
    summaries: dict[str, BatchSummary] = field(default_factory=dict)
    tmatrix: Path | None = None
    tmatrix_s: float = 0.0
    notes: list[str] = field(default_factory=list)
    continuity: ContinuityReport | None = None


def run_fit(
    crop_dir: str | Path, prefit: str | Path, library: str | Path | None,
    particle: ParticleConfig, out_dir: str | Path, *, pass_name: str = "both",
    initial_frames: int | None = None, static: str | Path | None = None,
    instrument: Instrument | None = None, override_instrument: bool = False,
    options: FrameFitSettings | None = None, engine: str | None = None,
    fixed: tuple[str, ...] = (), tmatrix: str = "auto", frames: list[int] | None = None,
    batch: BatchOptions | None = None, plot: bool = True, plot_frames: list[int] | None = None,
    outlier_factor: float = 4.0, numerical_aperture: ApertureChoice = FROM_INSTRUMENT,
    fit_na: bool = False, continuity: ContinuitySettings | None = None,
    tracking: TrackOptions | None = None,
) -> FitRun:
    """The DDA fit of a crop folder (see the module docstring).

    Parameters
    ----------
    crop_dir, prefit : str or Path
        Outputs of ``holofit crop`` and of ``holofit prefit`` for these crops (start
        positions and alpha).
    library : str or Path, optional
        Output of ``holofit library`` for these crops and this particle (start orientations);
        not needed for an isotropic particle.
    particle : ParticleConfig
        The particle model and its ``[dda]`` settings.
    out_dir : str or Path
        Where ``initial.csv``, ``static.json``, ``fit.csv`` (each with a sidecar), the plots
        and ``frames/`` go.
    pass_name : {"both", "initial", "final"}
        Which passes to run.
    initial_frames : int, optional
        Frames of the initial pass (spread over the movie where the particle has a
        T-matrix, else the first ones that can be fitted); default
        :func:`default_initial_frames` of the movie's fittable frames (said in ``notes``).
    static : str or Path, optional
        ``static.json`` for the final pass (default: ``OUT/static.json`` of the initial pass).
    options, engine, fixed
        How frames are fitted; the scattering engine (default: the particle config's); the
        parameters held at their start values (the particle config's for static ones).
    tmatrix : {"auto", "always", "never"}
        Serve the final pass from the particle's T-matrix (:mod:`holofit.fit.tmatrix_policy`).
    frames, batch
        Only these frames (both passes); parallel backend, resumption.
    instrument, override_instrument, plot, plot_frames, outlier_factor, numerical_aperture
        As for :func:`holofit.prefit.run_prefit`.
    fit_na : bool
        Fit the NA in every frame of both passes, starting from the one chosen.
    continuity : ContinuitySettings, optional
        The continuity sweeps after the final pass (default: on).
    tracking : TrackOptions, optional
        How the final pass follows the track of an anisotropic particle
        (:mod:`holofit.fit.tracked`; default: tracked); ``TrackOptions(warm=False)``:
        independent frames (``--no-tracking``).

    Raises
    ------
    CropSetError, StageInputError, ConfigError, ValueError, FitStageError
        With the file, frame or parameter at fault.
    """
    _check_arguments(particle, pass_name, tmatrix, initial_frames, fixed, engine)
    run = FitRun()
    # this process on one BLAS thread, as the workers are: OpenBLAS's pool spends 4-6x the
    # CPU on the small dense solves of a T-matrix build, the in-memory continuity refits and
    # the pictures (a rod's T-matrix: 7 s on one thread; 32-40 s of CPU and 39-60 s of wall
    # time on two busy cores)
    with threadpool_limits(limits=1, user_api="blas"), stage_inputs(
            crop_dir, frames, instrument, override_instrument, numerical_aperture,
            fit_na) as given:
        if given.crops.multi:
            raise FitStageError(
                f"{given.crops.table_path}: {len(given.crops.particles)} tracks (particle "
                f"{', '.join(map(str, given.crops.particles))}); run_fit fits one track: "
                "use holofit.fit.per_track.run_fit_tracks (as `holofit fit` does) or keep one "
                "track with `holofit crop --particle N`")
        passes = _FitPasses.open(
            given, particle, Path(prefit), None if library is None else Path(library),
            Path(out_dir), run, options or FrameFitSettings(), engine, tuple(fixed), fit_na,
            batch, plot, plot_frames, outlier_factor, continuity or ContinuitySettings(),
            tracking or TrackOptions())
        static_path = Path(static) if static is not None else passes.out / "static.json"
        if pass_name in ("initial", "both"):
            run.static = passes.initial(initial_frames, tmatrix)
            static_path = run.static if static is None else static_path
        if pass_name in ("final", "both"):
            passes.final(static_path, tmatrix)
    return run


def _check_arguments(particle: ParticleConfig, pass_name: str, tmatrix: str,
                     initial_frames: int | None, fixed: tuple[str, ...],
                     engine: str | None) -> None:
    """Refuse arguments that cannot work, before any input is read."""
    if pass_name not in PASSES:
        raise ValueError(f"pass must be one of {', '.join(PASSES)}, got {pass_name!r}")
    if tmatrix not in TMATRIX_CHOICES:
        raise ValueError(f"tmatrix must be one of {', '.join(TMATRIX_CHOICES)}, got {tmatrix!r}")
    if initial_frames is not None and initial_frames < 1:
        raise ValueError(f"initial_frames must be >= 1, got {initial_frames}")
    check_fixed(particle.model, tuple(fixed))
    check_policy(tmatrix, particle, engine, final_pass=pass_name != "initial")


def _check_library(meta: dict[str, Any], particle: ParticleConfig, path: Path) -> None:
    lib = meta.get("config", {}).get("particle")
    if not isinstance(lib, dict):
        return
    mine = particle.as_dict()
    if lib.get("model") != mine["model"]:
        raise StageInputError(f"{path}: library made for a {lib.get('model')!r}, but "
                              f"{particle.path or 'the particle'} is a {mine['model']!r}")
    diff = [k for k, v in mine.items() if k not in ("settings", "path") and lib.get(k) != v
            and k in lib]
    if diff:
        detail = ", ".join(f"{k} {lib[k]} vs {mine[k]}" for k in diff)
        raise StageInputError(
            f"{path}: library made for another {mine['model']} ({detail}): rerun "
            "`holofit library` with this particle config")


def _load(loader: FrameLoader, frame: int) -> FitPayload | Precomputed:
    """The shared loader's frame as the fit's payload."""
    got = loader(frame)
    if isinstance(got, Precomputed):
        return got
    return FitPayload(got.crop, got.corner, got.start,
                      tuple(Candidate(*c) for c in got.candidates))  # type: ignore[arg-type]


@dataclass
class _FitPasses:
    """The two passes of one :func:`run_fit`: their shared inputs and settings."""

    given: StageInputs
    particle: ParticleConfig
    inputs: list[Path]
    load: Any
    out: Path
    run: FitRun
    opts: FrameFitSettings
    engine: str | None
    fixed: tuple[str, ...]
    fit_na: bool
    batch: BatchOptions | None
    plot: bool
    plot_frames: list[int] | None
    outlier_factor: float
    cont: ContinuitySettings
    tracking: TrackOptions
    frame_loader: FrameLoader | None = None

    @classmethod
    def open(cls, given: StageInputs, particle: ParticleConfig, prefit: Path,
             library: Path | None, out: Path, *args: Any) -> _FitPasses:
        """Read the prefit's and the library's tables (checked against the crops and the
        particle) into the shared frame loader."""
        crops = given.crops
        # one lattice for both passes, whatever the fitted index does to the dipole rule
        particle = particle.with_fixed_lattice(given.instrument.optics)
        pre, _ = read_stage_table(prefit, crops, "prefit")
        lib_table = None
        if particle.model.anisotropic:
            if library is None:
                raise StageInputError(f"a {particle.model.kind} needs starting orientations: "
                                      "give the output of `holofit library` (--library)")
            lib_table, lib_meta = read_stage_table(library, crops, "library")
            _check_library(lib_meta, particle, library)
        frame_loader = FrameLoader(crops, pre, lib_table)
        inputs = [crops.table_path, prefit, *([library] if library else [])]
        return cls(given, particle, inputs, partial(_load, frame_loader), out, *args,
                   frame_loader=frame_loader)

    def initial(self, initial_frames: int | None, policy: str = "auto") -> Path:
        """The initial pass; writes ``static.json``, its path. An anisotropic particle with a
        T-matrix (``--tmatrix`` auto on a movie of at least
        :data:`~holofit.fit.tmatrix_policy.TMATRIX_MIN_FRAMES` frames, or always) has its
        frames spread over the movie, each seeded from the start statics' T-matrix
        (:mod:`holofit.fit.seeded`); without one, the pass follows the track from the first
        frames; with ``--no-tracking`` (or a sphere) the first frames are fitted each from
        the library (:func:`initial_choice`)."""
        crops = self.given.crops
        fittable = [f for f in self.given.frames
                    if crops.row(f).get("status") in FITTABLE_CROP_STATUSES]
        particle = initial_particle(self.particle)
        model = particle.model
        tracked = self.tracking.warm and self.tracking.initial and model.anisotropic
        seed = None
        if tracked:
            seeding = final_tmatrix(seed_particle(particle), self.given.instrument,
                                    self.engine, policy, len(fittable), self.out,
                                    self.local_workers(), name="tmatrix_start.npz",
                                    purpose="initial pass's poses (start statics)",
                                    build_options=SEED_BUILD)
            if seeding.path is not None:
                seed = str(seeding.path)
                self.run.notes += seeding.notes
        spread = seed is not None
        n_initial = initial_frames
        if n_initial is None:
            n_initial = default_initial_frames(len(fittable))
            which = (f"{n_initial} of the {len(fittable)} frames that can be fitted, spread "
                     "over the movie" if spread else
                     f"the first {n_initial} of the {len(fittable)} frames that can be fitted")
            self.run.notes.append(
                f"initial pass (every parameter free) on {which}: the default, 1 in "
                f"{INITIAL_SHARE}, at least {INITIAL_MIN}, at most {INITIAL_MAX} "
                "(--initial-frames N to choose)")
        chosen = initial_choice(fittable, [_overlapped(crops.row(f)) for f in fittable],
                                n_initial, spread=spread)
        if any(_overlapped(crops.row(f)) for f in (fittable if spread else fittable[:n_initial])):
            self.run.notes.append(
                "initial pass: frames without another track's overlapping hologram first "
                f"({sum(not _overlapped(crops.row(f)) for f in chosen)} of {len(chosen)})")
        if seed is not None:
            self.run.initial = self.one_pass("initial", particle, chosen, "initial.csv",
                                             seed_tmatrix=seed)
        elif tracked:
            self.run.initial = self.tracked_pass("initial", particle, chosen, "initial.csv")
        else:
            self.run.initial = self.one_pass("initial", particle, chosen, "initial.csv")
        return write_static(self.out / "static.json", self.run.initial,
                            read_table(self.run.initial), self.particle.model)

    def final(self, static_path: Path, policy: str) -> None:
        """The final pass on every frame, the static parameters fixed to ``static_path``'s."""
        model = self.particle.model
        settled = ParticleConfig(particle_with(model, read_static(static_path, model)),
                                 self.particle.settings, self.particle.path)
        tm = final_tmatrix(settled, self.given.instrument, self.engine, policy,
                           len(self.given.frames), self.out, self.local_workers())
        self.run.notes += tm.notes
        if tm.path is not None:
            self.run.tmatrix, self.run.tmatrix_s = tm.path, tm.seconds
        tm_path = None if tm.path is None else str(tm.path)
        if self.tracking.warm and model.anisotropic:
            self.run.final = self.tracked_pass("final", settled, self.given.frames,
                                               "fit.csv", static_doc(static_path), tm_path)
            return
        self.run.final = self.one_pass("final", settled, self.given.frames, "fit.csv",
                                       static_doc(static_path), tm_path)

    def local_workers(self) -> int:
        """Processes of this machine the stage may use (its ``-j``; every CPU by default; one
        with ``-j 0``), for work done in the driver (the T-matrix build)."""
        workers = self.batch.workers if self.batch is not None else None
        return available_cpus() if workers is None else max(workers, 1)

    def pass_opts(self, name: str) -> FrameFitSettings:
        """The frame-fit settings of a pass: the initial pass's fits (sizes free) stop within
        :data:`INITIAL_STOP_CHI2` of their minimum unless the settings ask for more."""
        if name != "initial":
            return self.opts
        return replace(self.opts, stop_chi2=max(self.opts.stop_chi2, INITIAL_STOP_CHI2))

    def one_pass(self, name: str, particle: ParticleConfig, frames: list[int],
                 table_name: str, static: dict[str, Any] | None = None,
                 tmatrix: str | None = None, seed_tmatrix: str | None = None) -> Path:
        """One pass through the stage skeleton; the path of its table."""
        cfg = FitConfig(particle, self.given.instrument, name, self.pass_opts(name),
                        self.engine, self.fixed, tmatrix=tmatrix, fit_na=self.fit_na,
                        seed_tmatrix=seed_tmatrix)
        table = self.table(cfg, table_name, static)
        self.run.summaries[name], _ = run_stage(
            fit_frame_task, cfg, frames, self.load, table, batch=self.batch,
            complete=partial(self.complete, cfg, table.path.stem))
        return table.path

    def tracked_pass(self, name: str, particle: ParticleConfig, frames: list[int],
                     table_name: str, static: dict[str, Any] | None = None,
                     tmatrix: str | None = None) -> Path:
        """A pass along the track (:mod:`holofit.fit.tracked`): the chunks through the stage
        skeleton into ``<stem>_chunks.csv``, stitched into the pass's table (outliers flagged,
        overlaps' disagreements in ``<stem>_overlaps.csv``), then sweeps and pictures."""
        cfg = FitConfig(particle, self.given.instrument, name, self.pass_opts(name),
                        self.engine, self.fixed, tmatrix=tmatrix, fit_na=self.fit_na)
        if name == "final":
            assert self.frame_loader is not None
            bar, note = final_bar(self.out / "initial.csv", cfg, self.frame_loader,
                                  self.cont.chi2_sigmas)
        else:
            bar, note = None, (f"{name} pass along the track: no chi^2 bar yet (warm fits "
                               "checked by status and step)")
        self.run.notes.append(note)
        # the final pass checks each initial frame against its initial-pass fit
        poses = initial_poses(self.out / "initial.csv") if name == "final" else {}
        overlap = OVERLAP if name == "final" else INITIAL_OVERLAP
        # the initial pass's direct DDA solves are too dear for the pole probes and the other
        # heights (tracking.py, steps 7-8: up to seven fits a frame); its rows are checked by their
        # level instead (initial_level.py) and each final frame against its own
        dear = {"pole_probes": 0, "recheck_rad": 0.0, "reopen_dz_um": ()}
        tracking = replace(self.tracking, frame=cfg.options,
                           **({} if name == "final" else dear))
        tcfg = TrackedConfig(cfg, tracking, bar, overlap)
        if name == "final":
            chunks = plan_chunks(frames, overlap, min_chunk=MIN_CHUNK)
        else:  # each run of consecutive frames its own chunks: no warm fit across a gap
            chunks = [c for part in consecutive_runs(frames)
                      for c in plan_chunks(part, overlap, min_chunk=initial_min_chunk(len(part)))]
        pass_table = self.table(cfg, table_name, static)
        path = pass_table.path
        columns = (*pass_table.columns, *TRACK_COLUMNS)
        key_doc = {"tracked": tcfg.as_dict(), "crops": self.given.crops.fingerprint(),
                   "outlier_factor": self.outlier_factor, "frames": frames}
        if name == "final":
            key_doc["initial_poses"] = sorted(poses.items())
        key = fingerprint(key_doc)
        meta = {**pass_table.meta, "tracking": {**tcfg.as_dict(), "chi2_bar_note": note,
                                                "chunks": [[c[0], c[-1]] for c in chunks]}}
        assert self.frame_loader is not None
        chunk_table = StageTable(self.out / f"{path.stem}_chunks.csv", ("chunk", *columns),
                                 meta, key, f"fit ({name}, tracked chunks)",
                                 key_columns=CHUNK_KEY)
        self.run.summaries[name], _ = run_stage(
            track_chunk_task, tcfg, [(i, c[0]) for i, c in enumerate(chunks)],
            chunk_loader(self.frame_loader, chunks, cfg.instrument.frame_rate_hz, poses),
            chunk_table, batch=self.batch)
        longest = max((len(c) for c in chunks), default=0)
        self.run.notes.append(f"{name} pass along the track: {len(chunks)} chunk(s) of up to "
                              f"{longest} frames (the batch's items), overlapping by {overlap}")
        if self.run.summaries[name].n_run == 0 and _fingerprint_of(path) == key:
            self.complete(cfg, path.stem, path)  # complete before this run (as one_pass)
            return path
        table, overlaps = stitch_table(chunk_table.path, chunks,
                                       particle.model.head_tail_symmetric)
        write_table(self.out / f"{path.stem}_overlaps.csv", overlaps)
        if len(overlaps):
            self.run.notes.append(f"{name} pass: {len(overlaps)} overlap frame(s) of the "
                                  f"chunks disagree ({path.stem}_overlaps.csv)")
        outlier_rule(self.outlier_factor)(table)
        meta["tracking"]["overlap_disagreements"] = len(overlaps)
        if poses:
            meta["tracking"]["initial_check"], check_note = initial_check_summary(table)
            self.run.notes.append(check_note)
        meta["batch"] = {"fingerprint": key, "complete": True, "frames_total": len(table)}
        staged = partial_path(path)
        write_table(staged, table.reindex(columns=list(columns)), meta)
        self.complete(cfg, path.stem, staged)
        os.replace(sidecar_path(staged), sidecar_path(path))
        os.replace(staged, path)  # the last file written: the run is complete
        return path

    def table(self, cfg: FitConfig, table_name: str,
              static: dict[str, Any] | None) -> StageTable:
        """A pass's table: the fit-table schema's columns and sidecar, its fingerprint."""
        inst, crops, model = cfg.instrument, self.given.crops, cfg.particle.model
        columns = fit_columns(model, cfg.free)
        meta = fit_table_meta(
            columns, kind=f"DDA fit table ({cfg.pass_name} pass)", config=cfg.as_dict(),
            inputs=self.inputs, status_unit=describe(FIT_STATUS_MEANINGS),
            frame_interval_s=1.0 / inst.frame_rate_hz if inst.frame_rate_hz else None,
            extra={"crops": crops.fingerprint(), "particle_model": model.kind,
                   "quality": outlier_sidecar(self.outlier_factor),
                   **({"static": static} if static else {})})
        key = fingerprint({"config": cfg.as_dict(), "crops": crops.fingerprint(),
                           "outlier_factor": self.outlier_factor})
        return StageTable(self.out / table_name, columns, meta, key,
                          f"fit ({cfg.pass_name})", finish=outlier_rule(self.outlier_factor))

    def complete(self, cfg: FitConfig, stem: str, table: Path) -> None:
        """The initial pass's rows clearly worse than its best ones flagged
        (:mod:`holofit.fit.initial_level`), the continuity sweeps (final pass), and pictures
        on the complete table."""
        if cfg.pass_name == "initial":
            flagged = flag_initial_table(table, self.cont.chi2_sigmas)
            if flagged:
                self.run.notes.append(
                    f"initial pass: {flagged} frame(s) fit clearly worse than its best quarter "
                    "of frames (poor_fit in initial.csv): left out of the static parameters "
                    "and of the final pass's chi^2 bar")
        if cfg.pass_name == "final" and self.cont.enabled and cfg.particle.model.anisotropic:
            self.run.continuity = continuity_sweeps(table, cfg, self.load, self.cont,
                                                    self.batch, self.outlier_factor)
        if self.plot:
            _plots(table, self.given.crops, cfg.particle.model, cfg.particle.theory(self.engine),
                   cfg.instrument, self.out, cfg.pass_name, self.plot_frames,
                   self.opts.far_field, stem)


def _overlapped(crop_row: dict[str, Any]) -> bool:
    """Whether the crop table marks this crop as overlapped by another track's hologram."""
    return str(crop_row.get("overlap", "")).strip().lower() in ("true", "1")


def initial_choice(fittable: list[int], overlapped: list[bool], n: int,
                   spread: bool = False) -> list[int]:
    """The initial pass's frames: ``n`` of ``fittable`` whose crop no other track's hologram
    overlaps, then (too few of those) the first overlapped ones; in frame order. The static
    parameters are best measured on a particle alone; a track whose frames all overlap is
    fitted on them, and the overlap refit (:mod:`holofit.fit.overlaps`) adds the neighbour's
    field.

    ``spread``: evenly spaced over the clean frames (the middle one of each of ``n`` equal
    runs), for frames fitted each on its own; else the first ``n``, for a pass that follows
    the track from frame to frame. The static parameters need orientations: on the Janus
    replicate the first 10 frames (all cap-down, within 0.1 s) gave a radius 3.6 nm and a cap
    4.4 nm off the truth, while 10 frames spread over the movie gave 0.8 and 0.4 nm
    (:mod:`holofit.fit.seeded`). Spread frames opened from the library's starts were tried
    first and cost 98-141 solves each, three of four in wrong minima; seeded from the start
    statics' T-matrix they cost 14-35."""
    clean = [f for f, o in zip(fittable, overlapped, strict=True) if not o]
    rest = [f for f, o in zip(fittable, overlapped, strict=True) if o]
    if spread and n < len(clean):
        clean = [clean[(2 * i + 1) * len(clean) // (2 * n)] for i in range(n)]
    return sorted((clean + rest)[:n])


def initial_min_chunk(n_frames: int) -> int:
    """The initial pass's shortest chunk for ``n_frames`` frames (:func:`plan_chunks`). A
    short initial pass (fewer than ``2 * INITIAL_MIN_CHUNK`` frames: ``--initial-frames``
    4-7, or a movie that short) is still cut in two, one chunk per worker of a 2-core
    machine: 4 initial frames of a Janus movie become two chunks of 2 frames (the initial
    pass's chunks do not overlap: :data:`holofit.fit.tracked.INITIAL_OVERLAP`), a library fit
    and a warm fit each (134 and 41, 112 and 100 DDA
    solves, measured), not one chunk of 4 frames on one worker while the other idles."""
    if n_frames >= 2 * INITIAL_MIN_CHUNK:
        return INITIAL_MIN_CHUNK
    return max(n_frames // 2, 2)


#: the precision of the initial pass's DDA solves where the particle's ``[dda]`` table does not
#: choose one (:func:`initial_particle`)
INITIAL_PRECISION = "single"
#: the initial pass's fits stop where the Gauss-Newton step predicts a chi^2 decrease of at
#: most this (:attr:`holofit.fit.frame.FrameFitSettings.stop_chi2`): one frame's static
#: parameters then sit within about one standard error of that frame's minimum, while they
#: scatter from frame to frame by ~5 standard errors (the 24-frame Janus movie: cap 41-47 nm
#: at 0.5 nm, radius 443-451 nm at 0.7 nm, n_cap 2.74-2.87 at 0.011); the median over the
#: frames is what the final pass uses
INITIAL_STOP_CHI2 = 1.0


def initial_particle(particle: ParticleConfig) -> ParticleConfig:
    """The particle config of the initial pass: its direct DDA solves use the single-precision
    FFT convolution (:data:`INITIAL_PRECISION`) unless the ``[dda]`` table sets ``precision``.

    The initial pass fits the static parameters with a direct solve per orientation and per
    static finite difference; single precision takes 0.5-0.7 times a double solve's time and
    changes the field by ~1e-7 of itself, far below the solver's tolerance (1e-5), which sets
    the model's and the finite differences' precision either way (the T-matrix build does the
    same: :func:`holofit.dda.tmatrix_build.build_tmatrix`). A particle without a ``[dda]``
    table (a sphere by Lorenz-Mie, an exact engine's model) is returned as it is.
    """
    dda = particle.settings.get("dda")
    if not isinstance(dda, dict) or "precision" in dda:
        return particle
    return replace(particle, settings={**particle.settings,
                                       "dda": {**dda, "precision": INITIAL_PRECISION}})


def _fingerprint_of(path: Path) -> str | None:
    """The batch fingerprint in ``path``'s sidecar (None: no table or no sidecar)."""
    side = sidecar_path(path)
    if not path.exists() or not side.exists():
        return None
    try:
        return json.loads(side.read_text()).get("batch", {}).get("fingerprint")
    except (OSError, ValueError):
        return None


def _plots(path: Path, crops: CropSet, model: ParticleModel, theory: ScatteringTheory,
           inst: Instrument, out: Path, name: str, frames: list[int] | None,
           far_field: bool, stem: str) -> None:
    from holofit.holomodel.plots import plot_table

    panels = [("x_um", "x (um)"), ("y_um", "y (um)"), ("z_um", "z (um)")]
    if model.anisotropic:
        panels += [("theta_rad", "theta (rad)"), ("psi_rad", "psi (rad)")]
    panels += [("alpha", "alpha")]
    panels += [(p.name, f"{p.name} ({p.unit})") for p in static_parameters(model)]
    panels += [("r2", "R^2"), ("delta_chi2", "runner-up delta chi^2"),
               ("fit_time_s", "fit time (s)")]
    plot_table(path, out / f"{stem}.png", panels, f"holofit fit ({name} pass)", f"{stem}.csv")
    write_frame_pictures(read_table(path), crops, model, theory, inst.optics,
                         inst.pixel_size_um, out / f"frames_{name}", f"fit ({name} pass)",
                         frames, far_field)

