"""``holofit fit``: the DDA fit of every frame (the paper's steps 5-6).

- **Initial pass** (``initial.csv``): every parameter free (position, orientation, alpha and
  the particle's static parameters: a rod's a, b, n; a Janus particle's core radius, cap
  thickness and both indices; a dimer's radii, gap and indices) on the first
  ``initial_frames`` frames, from the library's candidates and the prefit's position. The
  static parameters' robust average over the ``ok`` frames (median, with the spread as 1.4826
  times the median absolute deviation) goes to ``static.json``.
- **Final pass** (``fit.csv``): the static parameters fixed to those values (or to a
  ``static.json`` given), position, orientation and alpha fitted on every frame.
- **Continuity sweeps** (:mod:`holofit.fit.continuity`): frames of the final pass that look
  like a wrong local minimum are refitted from their good neighbours' orientations (each sweep
  a batch of its own, ``continuity/sweep_K.csv``, resumable); better fits replace their rows
  in ``fit.csv`` and frames still far from the data become ``poor_fit``.

Both passes run through the batch runner (parallel, resumable, failures recorded, a worker
keeps its engine and its caches across frames), write the fit-table schema
(:mod:`holofit.tables.fit`: ``holofit analyze`` reads ``fit.csv`` as it is), flag the movie's
outlier frames, and draw data / model / residual pictures of a few frames.
"""

from __future__ import annotations

import hashlib
import json
import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray
from threadpoolctl import threadpool_limits

from holofit.batch.aperture import FROM_INSTRUMENT, ApertureChoice, fit_instrument
from holofit.batch.runner import BatchOptions, BatchSummary, Precomputed, run_batch, run_frame
from holofit.cache import LRUCache
from holofit.config import ConfigError, Instrument, ParticleConfig
from holofit.dda.polarizability import INCIDENCE_INDEPENDENT
from holofit.dda.tmatrix_io import TMatrixMismatch
from holofit.fit.continuity import (
    ContinuityOptions,
    ContinuityReport,
    NeighbourStart,
    repair_by_continuity,
)
from holofit.fit.defaults import (
    INITIAL_MAX,
    INITIAL_MIN,
    INITIAL_SHARE,
    default_initial_frames,
)
from holofit.fit.frame import RUNNER_UP_COLUMNS, FrameFitOptions, fit_frame
from holofit.fitting.finish import outlier_rule, outlier_sidecar
from holofit.fitting.parameters import (
    APERTURE,
    particle_with,
    static_parameters,
    static_values,
)
from holofit.fitting.pictures import write_frame_pictures
from holofit.fitting.result import flag_outliers, result_columns, result_row
from holofit.io.tables import read_table, sidecar_path, write_json, write_table
from holofit.library.search import Candidate
from holofit.models import ParticleModel
from holofit.provenance import sidecar
from holofit.scattering.theory import ScatteringTheory
from holofit.status import FIT_STATUS_MEANINGS, FITTABLE_CROP_STATUSES, OK, SKIPPED, describe
from holofit.tables.cropset import CropSet, CropSetError, resolve_instrument
from holofit.tables.fit import column_unit
from holofit.tables.inputs import StageInputError, read_stage_table, usable_start

__all__ = [
    "FitConfig",
    "FitPayload",
    "FitRun",
    "FitStageError",
    "default_initial_frames",
    "fit_columns",
    "fit_frame_task",
    "read_static",
    "run_fit",
    "static_average",
]

PASSES = ("initial", "final", "both")
TMATRIX_CHOICES = ("auto", "always", "never")
#: final passes at least this long are served from a T-matrix by default
TMATRIX_MIN_FRAMES = 8


class FitStageError(RuntimeError):
    """A fit stage cannot go on (e.g. the initial pass left no frame to average)."""
#: spread of a normal sample from its median absolute deviation
MAD_TO_SIGMA = 1.4826


def _free(model: ParticleModel, pass_name: str, fixed: tuple[str, ...] = (),
          fit_na: bool = False) -> tuple[str, ...]:
    names = ["x_um", "y_um", "z_um", "orientation", "alpha"]
    if pass_name == "initial":
        names += [p.name for p in static_parameters(model)]
    if fit_na:
        names.append(APERTURE.name)
    return tuple(n for n in names if n not in fixed)


def fixable_names() -> dict[str, tuple[str, ...]]:
    """The static fit parameters of each particle model (``--fix`` can hold them), by kind;
    a voxel file's are ``n1, n2, ...`` (one per domain)."""
    from holofit.fitting.parameters import index_column
    from holofit.models import MODEL_TYPES

    return {kind: (*cls.size_fields, *cls.nonnegative_fields,
                   *(index_column(f) for f in cls.index_fields))
            for kind, cls in MODEL_TYPES.items() if kind != "voxels"}


def check_fixed(model: ParticleModel, fixed: tuple[str, ...]) -> None:
    """Refuse names in ``fixed`` that are not fit parameters of ``model`` (a typo)."""
    known = {"x_um", "y_um", "z_um", "orientation", "alpha"} | {
        p.name for p in static_parameters(model)}
    unknown = sorted(set(fixed) - known)
    if unknown:
        raise ValueError(f"cannot fix {', '.join(unknown)}: a {model.kind}'s fit parameters are "
                         f"{', '.join(sorted(known))}")


def fit_columns(model: ParticleModel, free: tuple[str, ...]) -> tuple[str, ...]:
    """Columns of a DDA fit table for ``model`` with parameters ``free``."""
    orient = ()
    if model.anisotropic:
        orient = ("theta_rad", "psi_rad", *(() if model.axisymmetric else ("phi_rad",)),
                  "ux", "uy", "uz")
    statics = tuple(p.name for p in static_parameters(model))
    optics = (APERTURE.name,) if APERTURE.name in free else ()
    values = ("x_um", "y_um", "z_um", *orient, "alpha", *statics, *optics)
    errors = ("x_um", "y_um", "z_um", *orient, "alpha", *(s for s in statics if s in free),
              *optics)
    return result_columns(values, errors, (*RUNNER_UP_COLUMNS, "n_masked"))


@dataclass(frozen=True)
class FitConfig:
    """Everything a worker needs for one pass (picklable).

    Attributes
    ----------
    particle : ParticleConfig
        The particle; its static parameters are the fit's start (initial pass) or fixed values
        (final pass).
    instrument : Instrument
        Optics and pixel size.
    pass_name : {"initial", "final"}
        Which pass.
    options : FrameFitOptions
        How each frame is fitted.
    engine : str, optional
        Scattering engine (default: the particle config's).
    fixed : tuple of str
        Parameters held at their start values in both passes (e.g. a dimer's ``gap_um``).
    tmatrix : str, optional
        The particle's T-matrix file (final pass): every orientation is then served from it,
        with analytic orientation columns of the Jacobian, instead of a DDA solve.
    fit_na : bool
        Fit the objective's numerical aperture (from the instrument's) in every frame.
    """

    particle: ParticleConfig
    instrument: Instrument
    pass_name: str
    options: FrameFitOptions = field(default_factory=FrameFitOptions)
    engine: str | None = None
    fixed: tuple[str, ...] = ()
    tmatrix: str | None = None
    fit_na: bool = False

    @property
    def free(self) -> tuple[str, ...]:
        return _free(self.particle.model, self.pass_name, self.fixed, self.fit_na)

    def as_dict(self) -> dict[str, Any]:
        return {"particle": self.particle.as_dict(), "instrument": self.instrument.as_dict(),
                "pass": self.pass_name, "free": list(self.free),
                "options": asdict(self.options), "engine": self.engine,
                "tmatrix": self.tmatrix is not None}

    def key(self) -> str:
        doc = json.dumps({k: v for k, v in self.as_dict().items() if k != "pass"},
                         sort_keys=True, default=str)
        return hashlib.sha256(doc.encode()).hexdigest()[:16]


@dataclass(frozen=True)
class FitPayload:
    """What the driver sends a worker for one frame."""

    crop: NDArray[np.float32]
    corner: tuple[int, int]
    start: dict[str, float]
    candidates: tuple[Candidate, ...]


#: per worker process: one engine per particle configuration, with its caches
_THEORIES: LRUCache[str, ScatteringTheory] = LRUCache(2)


def fit_frame_task(config: FitConfig, frame: int, payload: FitPayload) -> dict[str, Any]:
    """Fit one frame; the frame function of both passes."""
    inst = config.instrument
    key = json.dumps({"particle": config.particle.as_dict(), "engine": config.engine},
                     sort_keys=True, default=str)
    def make_theory() -> ScatteringTheory:
        theory = config.particle.theory(config.engine, fixed_lattice_for=inst.optics)
        if config.tmatrix is not None:
            theory.tmatrix(config.particle.model, inst.optics, path=config.tmatrix)
        return theory

    theory = _THEORIES.get_or_create(key + str(config.tmatrix), make_theory)
    start = payload.start
    result = fit_frame(payload.crop, payload.corner, inst.pixel_size_um, theory,
                       config.particle.model, inst.optics,
                       (start["x_um"], start["y_um"], start["z_um"]), start["alpha"],
                       payload.candidates, config.free, config.options, seed=frame)
    time_s = frame / inst.frame_rate_hz if inst.frame_rate_hz else math.nan
    return result_row(frame, time_s, result)


def static_average(table: pd.DataFrame, model: ParticleModel) -> dict[str, Any]:
    """Robust average of the static parameters over a table's ``ok`` rows.

    Returns
    -------
    dict
        ``{"values": {name: median}, "spread": {name: 1.4826 MAD}, "mean": ..., "std": ...,
        "n_frames": n}``.

    Raises
    ------
    FitStageError
        No ``ok`` row.
    """
    ok = table[table["status"] == OK]
    if len(ok) < 1:
        raise FitStageError("the initial pass has no ok frame: no static parameters to fix "
                            "(see initial.csv's status and message)")
    out: dict[str, Any] = {"values": {}, "spread": {}, "mean": {}, "std": {},
                           "n_frames": len(ok)}
    for p in static_parameters(model):
        v = ok[p.name].to_numpy(dtype=float)
        v = v[np.isfinite(v)]
        med = float(np.median(v))
        out["values"][p.name] = med
        out["spread"][p.name] = (float(MAD_TO_SIGMA * np.median(np.abs(v - med)))
                                 if v.size >= 3 else math.nan)
        out["mean"][p.name] = float(np.mean(v))
        out["std"][p.name] = float(np.std(v, ddof=1)) if v.size > 1 else 0.0
    return out


def read_static(path: str | Path, model: ParticleModel) -> dict[str, float]:
    """The static parameters of a ``static.json`` (checked against ``model``).

    Raises
    ------
    ConfigError
        Missing file, not JSON, another particle model, or a missing parameter.
    """
    path = Path(path)
    try:
        doc = json.loads(path.read_text())
    except FileNotFoundError:
        raise ConfigError(f"{path}: static-parameter file not found") from None
    except ValueError as exc:
        raise ConfigError(f"{path}: not valid JSON ({exc})") from None
    if doc.get("particle_model") not in (None, model.kind):
        raise ConfigError(f"{path}: static parameters of a {doc.get('particle_model')!r}, "
                          f"not of this {model.kind!r}")
    values = doc.get("values", {})
    missing = [p.name for p in static_parameters(model) if p.name not in values]
    if missing:
        raise ConfigError(f"{path}: missing static parameter(s) {', '.join(missing)}")
    return {k: float(values[k]) for k in (p.name for p in static_parameters(model))}


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


def _candidates(row: dict[str, Any] | None, n_max: int) -> tuple[Candidate, ...]:
    if row is None:
        return ()
    out = []
    for i in range(1, n_max + 1):
        vals = [row.get(f"c{i}_{q}") for q in ("psi_rad", "theta_rad", "phi_rad", "r2")]
        if all(isinstance(v, int | float) and math.isfinite(float(v)) for v in vals[:3]):
            out.append(Candidate(*(float(v) for v in vals)))  # type: ignore[arg-type]
    return tuple(out)


def run_fit(
    crop_dir: str | Path,
    prefit: str | Path,
    library: str | Path | None,
    particle: ParticleConfig,
    out_dir: str | Path,
    *,
    pass_name: str = "both",
    initial_frames: int | None = None,
    static: str | Path | None = None,
    instrument: Instrument | None = None,
    override_instrument: bool = False,
    options: FrameFitOptions | None = None,
    engine: str | None = None,
    fixed: tuple[str, ...] = (),
    tmatrix: str = "auto",
    frames: list[int] | None = None,
    batch: BatchOptions | None = None,
    plot: bool = True,
    plot_frames: list[int] | None = None,
    outlier_factor: float = 4.0,
    numerical_aperture: ApertureChoice = FROM_INSTRUMENT,
    fit_na: bool = False,
    continuity: ContinuityOptions | None = None,
) -> FitRun:
    """The DDA fit of a crop folder (see the module docstring).

    Parameters
    ----------
    crop_dir : str or Path
        Output of ``holofit crop``.
    prefit : str or Path
        Output of ``holofit prefit`` for these crops (start positions and alpha).
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
        Frames of the initial pass (the first ones that can be fitted); default
        :func:`default_initial_frames` of the movie's fittable frames (the choice is in
        ``notes``).
    static : str or Path, optional
        ``static.json`` for the final pass (default: ``OUT/static.json`` from the initial
        pass).
    instrument, override_instrument
        As for :func:`holofit.prefit.run_prefit`.
    options : FrameFitOptions, optional
        How frames are fitted.
    engine : str, optional
        Scattering engine (default: the particle config's).
    fixed : tuple of str
        Parameters held at their start values (the particle config's for static ones).
    tmatrix : {"auto", "always", "never"}
        Serve the final pass from the particle's T-matrix (built once in this process from DDA
        solves, saved as ``OUT/tmatrix.npz`` and loaded by every worker; exact to the solver's
        precision at every orientation). ``auto``: for the built-in engine when the final pass
        has at least :data:`TMATRIX_MIN_FRAMES` frames (a rod's build costs about as much as
        five frames fitted with direct solves).
    frames : list of int, optional
        Only these frames (both passes).
    batch : BatchOptions, optional
        Parallel backend, resumption.
    plot, plot_frames, outlier_factor
        As for :func:`holofit.prefit.run_prefit`.
    numerical_aperture : float, None or "instrument"
        The objective's NA the model is imaged with (:mod:`holofit.fitting.aperture`): the
        instrument's (default), another value, or None for the ideal model.
    fit_na : bool
        Fit the NA in every frame of both passes, starting from that one.
    continuity : ContinuityOptions, optional
        The continuity sweeps after the final pass (default: on).

    Returns
    -------
    FitRun

    Raises
    ------
    CropSetError, StageInputError, ConfigError, ValueError
        With the file, frame or parameter at fault.
    """
    if pass_name not in PASSES:
        raise ValueError(f"pass must be one of {', '.join(PASSES)}, got {pass_name!r}")
    if tmatrix not in TMATRIX_CHOICES:
        raise ValueError(f"tmatrix must be one of {', '.join(TMATRIX_CHOICES)}, got {tmatrix!r}")
    if initial_frames is not None and initial_frames < 1:
        raise ValueError(f"initial_frames must be >= 1, got {initial_frames}")
    opts = options or FrameFitOptions()
    cont = continuity or ContinuityOptions()
    check_fixed(particle.model, tuple(fixed))
    if tmatrix == "always" and particle.model.anisotropic and pass_name != "initial":
        why_not = _no_tmatrix_reason(particle.theory(engine))
        if why_not:  # said before any frame is fitted
            raise FitStageError(f"--tmatrix always: {why_not} (or use --tmatrix never)")
    out = Path(out_dir)
    run = FitRun()
    model = particle.model
    # this process on one BLAS thread, as the workers are: OpenBLAS's pool spends 4-6x the
    # CPU on the small dense solves of a T-matrix build, the in-memory continuity refits and
    # the pictures (a rod's T-matrix: 7 s on one thread; 32-40 s of CPU and 39-60 s of wall
    # time on two busy cores)
    with threadpool_limits(limits=1, user_api="blas"), CropSet(crop_dir) as crops:
        inst = fit_instrument(resolve_instrument(crops, instrument, override_instrument),
                              numerical_aperture, fit_na)
        # one lattice for both passes, whatever the fitted index does to the dipole rule
        particle = particle.with_fixed_lattice(inst.optics)
        pre, _ = read_stage_table(prefit, crops, "prefit")
        lib_table: pd.DataFrame | None = None
        n_cand = 0
        if model.anisotropic:
            if library is None:
                raise StageInputError(f"a {model.kind} needs starting orientations: give the "
                                      "output of `holofit library` (--library)")
            lib_table, lib_meta = read_stage_table(library, crops, "library")
            _check_library(lib_meta, particle, Path(library))
            n_cand = sum(1 for c in lib_table.columns if c.endswith("_theta_rad"))
        todo = crops.frames if frames is None else [int(f) for f in frames]
        unknown = sorted(set(todo) - set(crops.frames))
        if unknown:
            raise CropSetError(f"{crops.table_path}: no frame(s) {unknown[:5]}")

        def load(frame: int) -> FitPayload | Precomputed:
            crow = crops.row(frame)
            if crow.get("status") not in FITTABLE_CROP_STATUSES:
                return Precomputed({"status": SKIPPED,
                                    "message": f"crop stage: {crow.get('status')}"})
            prow = pre.loc[frame].to_dict() if frame in pre.index else None
            why = usable_start(prow)
            if why:
                return Precomputed({"status": SKIPPED, "message": f"prefit: {why}"})
            assert prow is not None
            cands: tuple[Candidate, ...] = ()
            if lib_table is not None:
                lrow = lib_table.loc[frame].to_dict() if frame in lib_table.index else None
                cands = _candidates(lrow, n_cand)
                if not cands:
                    status = lrow.get("status") if lrow else "missing"
                    return Precomputed({"status": SKIPPED,
                                        "message": f"library: no candidate (status {status})"})
            return FitPayload(crops.crop(frame),
                              (int(crow["corner_row"]), int(crow["corner_col"])),
                              {k: float(prow[k]) for k in ("x_um", "y_um", "z_um", "alpha")},
                              cands)

        def one_pass(name: str, cfg_particle: ParticleConfig, pass_frames: list[int],
                     table_name: str, static_doc: dict[str, Any] | None = None,
                     tmatrix_path: str | None = None) -> Path:
            cfg = FitConfig(cfg_particle, inst, name, opts, engine, tuple(fixed),
                            tmatrix=tmatrix_path, fit_na=fit_na)
            completed: list[Path] = []

            def complete(table: Path) -> None:
                """Continuity sweeps and pictures on the complete table, before it is
                published under its name (the last file written: make waits for it)."""
                if name == "final" and cont.enabled and model.anisotropic:
                    run.continuity = _continuity_sweeps(table, cfg, load, cont, batch,
                                                        outlier_factor)
                if plot:
                    _plots(table, crops, cfg_particle.model, cfg_particle.theory(engine), inst,
                           out, name, plot_frames, opts.far_field, Path(table_name).stem)
                completed.append(table)

            path = batch_pass(cfg, pass_frames, table_name, static_doc, complete)
            if not completed:  # the table was complete before this run: as before, from it
                complete(path)
            return path

        def batch_pass(cfg: FitConfig, pass_frames: list[int], table_name: str,
                       static_doc: dict[str, Any] | None,
                       complete: Callable[[Path], None]) -> Path:
            name = cfg.pass_name
            columns = fit_columns(model, cfg.free)
            units = {c: column_unit(c) for c in columns}
            units["status"] = describe(FIT_STATUS_MEANINGS)
            meta = sidecar(
                kind=f"DDA fit table ({name} pass)", units=units, config=cfg.as_dict(),
                inputs=[crops.table_path, Path(prefit), *([Path(library)] if library else [])],
                extra={"crops": crops.fingerprint(), "particle_model": model.kind,
                       "quality": outlier_sidecar(outlier_factor),
                       **({"static": static_doc} if static_doc else {}),
                       **({"frame_interval_s": 1.0 / inst.frame_rate_hz}
                          if inst.frame_rate_hz else {})},
            )
            fingerprint = hashlib.sha256(json.dumps(
                {"config": cfg.as_dict(), "crops": crops.fingerprint(),
                 "outlier_factor": outlier_factor}, sort_keys=True,
                default=str).encode()).hexdigest()[:16]
            path = out / table_name
            run.summaries[name] = run_batch(fit_frame_task, cfg, pass_frames, load, path,
                                            columns, fingerprint=fingerprint, meta=meta,
                                            options=batch, desc=f"fit ({name})",
                                            finish=outlier_rule(outlier_factor),
                                            before_publish=complete)
            return path

        static_path = Path(static) if static is not None else out / "static.json"
        if pass_name in ("initial", "both"):
            fittable = [f for f in todo if crops.row(f).get("status") in FITTABLE_CROP_STATUSES]
            n_initial = initial_frames
            if n_initial is None:
                n_initial = default_initial_frames(len(fittable))
                run.notes.append(
                    f"initial pass (every parameter free) on the first {n_initial} of the "
                    f"{len(fittable)} frames that can be fitted: the default, 1 in "
                    f"{INITIAL_SHARE}, at least {INITIAL_MIN}, at most {INITIAL_MAX} "
                    "(--initial-frames N to choose)")
            run.initial = one_pass("initial", particle, fittable[:n_initial], "initial.csv")
            avg = static_average(read_table(run.initial), model)
            write_json(out / "static.json", {
                **sidecar(kind="static parameters (robust average of the initial pass)",
                          units={p.name: p.unit for p in static_parameters(model)},
                          inputs=[run.initial]),
                "particle_model": model.kind, **avg,
                "start": dict(static_values(model)),
            })
            run.static = out / "static.json"
            static_path = run.static if static is None else static_path
        if pass_name in ("final", "both"):
            values = read_static(static_path, model)
            settled = ParticleConfig(particle_with(model, values), particle.settings,
                                     particle.path)
            doc = json.loads(static_path.read_text())
            static_doc = {k: doc[k] for k in ("values", "spread", "n_frames") if k in doc}
            tm_path = _final_tmatrix(settled, inst, engine, tmatrix, len(todo), out, run)
            run.final = one_pass("final", settled, todo, "fit.csv", static_doc, tm_path)
    return run


#: the refits of a continuity sweep: at most two neighbour starts, no mirror
_SWEEP_STARTS = 2
#: a sweep with fewer frames runs in this process, in memory (its engine kept from sweep to
#: sweep, no table written): the last sweeps, eating a long run of bad frames from its ends,
#: have a few frames and a few seconds each
_SERIAL_SWEEP_FRAMES = 8


def _continuity_sweeps(path: Path, cfg: FitConfig, load: Any, cont: ContinuityOptions,
                       batch: BatchOptions | None, outlier_factor: float) -> ContinuityReport:
    """Run the continuity sweeps on the final pass's table and write it back (atomically).

    Each sweep is a batch of its own (``continuity/sweep_K.csv`` beside ``fit.csv``, keyed on
    the table it started from), so an interrupted run resumes where it stopped; a table whose
    sidecar records sweeps with these settings is left as it is.
    """
    meta = json.loads(sidecar_path(path).read_text())
    key = hashlib.sha256(json.dumps(
        {"batch": meta.get("batch", {}).get("fingerprint"), "continuity": asdict(cont)},
        sort_keys=True).encode()).hexdigest()[:16]
    done = meta.get("continuity")
    if isinstance(done, dict) and done.get("key") == key:
        return ContinuityReport(**{k: done[k] for k in ContinuityReport.__dataclass_fields__
                                   if k in done})
    model = cfg.particle.model
    columns = fit_columns(model, cfg.free)
    sweep_cfg = replace(cfg, options=replace(cfg.options, n_starts=_SWEEP_STARTS, mirror=False))
    folder = path.parent / "continuity"

    def refit(sweep: int, starts: dict[int, NeighbourStart]) -> pd.DataFrame:
        def load_sweep(frame: int) -> FitPayload | Precomputed:
            payload = load(frame)
            if isinstance(payload, Precomputed):
                return payload
            s = starts[frame]
            return FitPayload(payload.crop, payload.corner,
                              {**payload.start, "z_um": s.z_um, "alpha": s.alpha},
                              s.candidates)

        fingerprint = hashlib.sha256(json.dumps(
            {"key": key, "sweep": sweep,
             "starts": {f: [s.sources, [(c.psi, c.theta, c.phi) for c in s.candidates],
                            s.z_um, s.alpha] for f, s in sorted(starts.items())}},
            sort_keys=True, default=str).encode()).hexdigest()[:16]
        sweep_meta = {**{k: v for k, v in meta.items() if k not in ("batch", "continuity")},
                      "kind": f"DDA fit table (continuity sweep {sweep}: refits from the "
                              "neighbours' orientations)"}
        out = folder / f"sweep_{sweep}.csv"
        if len(starts) < _SERIAL_SWEEP_FRAMES:
            rows = []
            for frame in sorted(starts):
                payload = load_sweep(frame)
                if not isinstance(payload, Precomputed):
                    rows.append(run_frame(fit_frame_task, sweep_cfg, frame, payload))
            return pd.DataFrame(rows, columns=list(columns))
        run_batch(fit_frame_task, sweep_cfg, sorted(starts), load_sweep, out, columns,
                  fingerprint=fingerprint, meta=sweep_meta, options=batch,
                  desc=f"fit (continuity {sweep})")
        return read_table(out)

    table, report = repair_by_continuity(
        read_table(path), refit, cont, head_tail=model.head_tail_symmetric,
        ambiguity_chi2=cfg.options.ambiguity_chi2,
        refinish=lambda t: flag_outliers(t, outlier_factor))
    meta["continuity"] = {**report.as_dict(), "key": key, "settings": asdict(cont),
                          "sweeps_folder": str(folder)}
    write_table(path, table[list(columns)], meta)
    return report


def _final_tmatrix(particle: ParticleConfig, inst: Instrument, engine: str | None,
                   policy: str, n_frames: int, out: Path, run: FitRun) -> str | None:
    """Build (or reuse) the final pass's T-matrix when the policy asks for one; its path."""
    model = particle.model
    if policy == "never" or not model.anisotropic:
        return None
    if policy == "auto" and n_frames < TMATRIX_MIN_FRAMES:
        return None
    theory = particle.theory(engine, fixed_lattice_for=inst.optics)
    if getattr(theory, "own_tmatrix", False):
        run.notes.append(f"final pass served by the {theory.name} engine's own T-matrix "
                         "(one solve per geometry, every orientation by rotation)")
        return None
    why_not = _no_tmatrix_reason(theory)
    if why_not:
        if policy == "always":
            raise FitStageError(f"--tmatrix always: {why_not} (or use --tmatrix never)")
        run.notes.append(f"final pass by direct DDA solves: {why_not}")
        return None
    path = out / "tmatrix.npz"
    t0 = time.perf_counter()
    reused = path.exists()
    try:
        theory.tmatrix(model, inst.optics, path=str(path))
    except TMatrixMismatch:
        # made for other static parameters or settings (an earlier run): build anew
        path.unlink()
        theory.tmatrix(model, inst.optics, path=str(path))
        reused = False
    run.tmatrix = path
    run.tmatrix_s = time.perf_counter() - t0
    run.notes.append(f"final pass served from the particle's T-matrix {path} "
                     f"({'loaded' if reused else 'built'} in {run.tmatrix_s:.1f} s)")
    return str(path)


def _no_tmatrix_reason(theory: ScatteringTheory) -> str:
    """Why ``theory`` cannot serve a T-matrix ('' if it can)."""
    if getattr(theory, "own_tmatrix", False):
        return ""
    if not hasattr(theory, "tmatrix"):
        return f"the {theory.name} engine has no T-matrix (use --engine builtin)"
    settings = getattr(theory, "settings", None)
    kind = getattr(settings, "polarizability", None)
    if kind is not None and kind not in INCIDENCE_INDEPENDENT:
        return (f"polarizability {kind!r} depends on the incident wave, so the lattice has no "
                f"T-matrix (the particle config's [dda] polarizability: one of "
                f"{', '.join(INCIDENCE_INDEPENDENT)})")
    return ""


def _plots(path: Path, crops: CropSet, model: ParticleModel, theory: ScatteringTheory,
           inst: Instrument, out: Path, name: str, frames: list[int] | None,
           far_field: bool, stem: str) -> None:
    from holofit.fitting.plots import plot_table

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

