"""``holofit library``: the best starting orientations of every frame (the paper's steps 3-4).

For each frame, the crop is sampled on a polar grid about the prefit's (x, y) and compared, by
R^2, with the particle's holograms at the prefit's height over a grid of orientations
(:mod:`holofit.library.search`); the best few local maxima, at least ``min_separation_deg``
apart, are the frame's candidates (``library.csv``, schema :mod:`holofit.tables.library`).
Frames run through the stage skeleton (:mod:`holofit.batch.stage`: parallel, resumable,
failures recorded); each worker solves the library's tilts once and keeps them for all its
frames, and the frames run in the order of their rounded prefit heights (:func:`by_height`),
so that a worker computes the tilts' fields at a height once.

Grid resolution: tilts every ``tilt_step_deg`` (10 deg by default) and ``n_phi`` azimuths
(128: 2.8 deg). The DDA fit converges from an error of half a step (5 deg in tilt): its basin
is far wider, and the fit, not the library, sets the final precision (docs: user guide,
"library").
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, replace
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from holofit.batch import BatchSettings, BatchSummary, Precomputed
from holofit.batch.options import available_cpus
from holofit.batch.stage import FrameLoader, StageTable, fingerprint, run_stage, stage_inputs
from holofit.batch.worker import worker_resource
from holofit.config import ConfigError, Instrument, ParticleConfig
from holofit.library.polar import polar_grid, sample_crop
from holofit.library.search import (
    HEIGHT_STEP_UM,
    OrientationLibrary,
    pick_candidates,
    tilt_grid,
)
from holofit.library.tilts import TILTS_FILE, load_tilts, solve_tilts
from holofit.provenance import sidecar
from holofit.status import OK
from holofit.tables.crop import keyed_columns
from holofit.tables.cropset import CropSet
from holofit.tables.inputs import read_stage_table
from holofit.tables.library import candidate_columns, library_columns, library_units

__all__ = [
    "LibraryConfig",
    "LibraryPayload",
    "LibraryResult",
    "LibrarySettings",
    "by_height",
    "candidate_columns",
    "library_frame",
    "run_library",
]


@dataclass(frozen=True)
class LibrarySettings:
    """How the library is built and searched.

    Attributes
    ----------
    tilt_step_deg : float
        Grid step of the tilt (and spin), deg.
    n_phi : int
        Azimuths of the polar grid: the psi resolution is ``360 / n_phi`` deg.
    n_candidates : int
        Candidates kept per frame.
    min_separation_deg : float
        Candidates are at least this far apart (angle between axes), deg.
    rho_max_px : float, optional
        Radius of the polar grid, pixels (default: half the crop's smaller side, less one).
    """

    tilt_step_deg: float = 10.0
    n_phi: int = 128
    n_candidates: int = 4
    min_separation_deg: float = 20.0
    rho_max_px: float | None = None

    def __post_init__(self) -> None:
        if not 0.5 <= self.tilt_step_deg <= 45:
            raise ValueError(f"tilt_step_deg must be in [0.5, 45], got {self.tilt_step_deg}")
        if self.n_phi < 16 or self.n_candidates < 1:
            raise ValueError("n_phi must be >= 16 and n_candidates >= 1")


@dataclass(frozen=True)
class LibraryConfig:
    """Everything a worker needs (picklable)."""

    particle: ParticleConfig
    instrument: Instrument
    settings: LibrarySettings = field(default_factory=LibrarySettings)
    engine: str | None = None
    #: the tilts solved by the driver (:mod:`holofit.library.tilts`); None: each worker
    #: solves them (not part of the configuration: the same scores either way)
    tilts: str | None = None

    def as_dict(self) -> dict[str, Any]:
        return {"particle": self.particle.as_dict(), "instrument": self.instrument.as_dict(),
                "settings": asdict(self.settings), "engine": self.engine}

    def key(self) -> str:
        return fingerprint(self.as_dict())


@dataclass(frozen=True)
class LibraryPayload:
    """What the driver sends a worker for one frame."""

    crop: NDArray[np.float32]
    corner: tuple[int, int]
    start: dict[str, float]


#: the precision of the library's DDA solves (:func:`new_library`)
LIBRARY_PRECISION = "single"

def new_library(config: LibraryConfig) -> OrientationLibrary:
    """The configuration's library, nothing solved yet.

    Its DDA solves use the single-precision FFT convolution (:data:`LIBRARY_PRECISION`)
    unless the particle's ``[dda]`` table sets ``precision``: the library only ranks starting
    orientations, and single precision changes a tilt's field by ~1e-7 of itself at a
    fraction of the time (docs: validation, "the DDA").
    """
    model = config.particle.model
    tilts = tilt_grid(model, math.radians(config.settings.tilt_step_deg))
    particle = config.particle
    dda = particle.settings.get("dda")
    if isinstance(dda, dict) and "precision" not in dda:
        dda = {**dda, "precision": LIBRARY_PRECISION}
        particle = replace(particle, settings={**particle.settings, "dda": dda})
    theory = particle.theory(config.engine, fixed_lattice_for=config.instrument.optics)
    return OrientationLibrary(theory, model, config.instrument.optics, tilts)


def _library(config: LibraryConfig) -> OrientationLibrary:
    def make() -> OrientationLibrary:
        lib = new_library(config)
        if config.tilts is not None:
            load_tilts(lib, Path(config.tilts), config.key())
        return lib

    return worker_resource("library", config.key(), make, size=2)


def library_frame(config: LibraryConfig, frame: int, payload: LibraryPayload) -> dict[str, Any]:
    """Candidates of one frame; the frame function of the library batch."""
    inst = config.instrument
    s = config.settings
    lib = _library(config)
    px = inst.pixel_size_um
    start = payload.start
    rows, cols = payload.crop.shape
    # one grid for every frame (the library's fields on it are reused between frames at
    # nearly the same height); samples off the crop get no weight
    rho_max_px = s.rho_max_px if s.rho_max_px is not None else min(rows, cols) / 2 - 1
    rho_max = rho_max_px * px
    grid = polar_grid((start["x_um"], start["y_um"]), rho_max, px, s.n_phi)
    data, weights = sample_crop(payload.crop, payload.corner, px, grid)
    if np.count_nonzero(weights) < 0.25 * weights.size:
        raise ValueError("the prefit position leaves less than a quarter of the library's polar "
                         "grid on the crop")
    position = (start["x_um"], start["y_um"], start["z_um"])
    scores = lib.scores(grid, data, weights, position, start["alpha"])
    cands = pick_candidates(scores, lib.tilts, grid.phi, config.particle.model,
                            s.n_candidates, math.radians(s.min_separation_deg))
    row: dict[str, Any] = {"frame": frame, **{k: start[k] for k in ("x_um", "y_um", "z_um",
                                                                    "alpha")},
                           "n_candidates": len(cands), "status": OK, "message": ""}
    for i, c in enumerate(cands, 1):
        row.update({f"c{i}_psi_rad": c.psi, f"c{i}_theta_rad": c.theta, f"c{i}_phi_rad": c.phi,
                    f"c{i}_r2": c.r2})
    return row


@dataclass
class LibraryResult:
    """What :func:`run_library` wrote."""

    table: Path
    summary: BatchSummary
    plot: Path | None


def run_library(
    crop_dir: str | Path,
    prefit: str | Path,
    particle: ParticleConfig,
    out_dir: str | Path,
    *,
    instrument: Instrument | None = None,
    override_instrument: bool = False,
    settings: LibrarySettings | None = None,
    engine: str | None = None,
    frames: list[int] | None = None,
    batch: BatchSettings | None = None,
    plot: bool = True,
) -> LibraryResult:
    """Candidate orientations of every frame; writes ``OUT/library.csv`` (+ sidecar, plot).

    Parameters
    ----------
    crop_dir : str or Path
        Output folder of ``holofit crop``.
    prefit : str or Path
        Output folder (or table) of ``holofit prefit`` for these crops: the library is computed
        at each frame's prefit position and alpha.
    particle : ParticleConfig
        The particle model (and its ``[dda]`` settings).
    out_dir : str or Path
        Where ``library.csv``, its sidecar and ``library.png`` go.
    instrument, override_instrument
        As for :func:`holofit.prefit.run_prefit`.
    settings : LibrarySettings, optional
        Grid and candidates.
    engine : str, optional
        Scattering engine (default: the particle config's).
    frames : list of int, optional
        Only these frames.
    batch : BatchSettings, optional
        Parallel backend, resumption.
    plot : bool
        Write ``library.png`` (best candidate against frame).

    Raises
    ------
    CropSetError, StageInputError
        Incomplete crop folder; prefit table missing or made from other crops.
    ConfigError
        An isotropic particle (a sphere needs no library).
    """
    if not particle.model.anisotropic:
        raise ConfigError(f"{particle.path}: a {particle.model.kind} looks the same in every "
                         "orientation; it needs no library")
    settings = settings or LibrarySettings()
    out = Path(out_dir)
    with stage_inputs(crop_dir, frames, instrument, override_instrument) as given:
        pre, _ = read_stage_table(prefit, given.crops, "prefit")
        config = LibraryConfig(particle, given.instrument, settings, engine)
        table = _library_table(config, given.crops, Path(prefit), out)
        config = _shared_tilts(config, batch, len(given.frames), out)

        def pictures(table_path: Path) -> Path:
            """``library.png`` (:func:`run_stage`'s ``complete``)."""
            from holofit.holomodel.plots import plot_table

            return plot_table(
                table_path, out / "library.png",
                (("c1_theta_rad", "best theta (rad)"), ("c1_psi_rad", "best psi (rad)"),
                 ("c1_r2", "best R^2"), ("c2_r2", "second R^2"),
                 ("z_um", "prefit z (um)"), ("fit_time_s", "time per frame (s)")),
                "holofit library", "library.csv")

        summary, png = run_stage(library_frame, config,
                                 by_height(given.frames, given.crops, pre,
                                           lanes=_local_workers(batch, len(given.frames))),
                                 partial(_load, FrameLoader(given.crops, pre)), table,
                                 batch=batch, complete=pictures if plot else None)
    return LibraryResult(table.path, summary, png)


def by_height(frames: Sequence[Any], crops: CropSet, prefit: pd.DataFrame,
              step_um: float = HEIGHT_STEP_UM, lanes: int = 1) -> list[Any]:
    """``frames`` in the order of their prefit heights rounded to ``step_um`` (frame order
    within a step; frames without a height last), the sorted list cut into ``lanes`` runs
    that take turns (one per worker: workers that take the next frame in turn each stay at
    their own heights).

    A worker keeps the tilts' fields on the polar grid for the last few rounded heights
    (:class:`~holofit.library.search.OrientationLibrary`), and a frame at a height it holds
    costs only the correlations: in frame order a diffusing particle comes back to a height
    only now and then, in this order every frame at a height follows the first. The table is
    written in key order whatever the order of the work.
    """
    heights = prefit["z_um"].to_dict() if "z_um" in prefit else {}

    def rank(item: tuple[int, Any]) -> tuple[bool, float, int]:
        position, frame = item
        key = crops.key(frame) if hasattr(crops, "key") else frame
        z = heights.get(key, math.nan)
        step = round(float(z) / step_um) if math.isfinite(z) else math.inf
        return (not math.isfinite(step), step, position)

    ordered = [frame for _, frame in sorted(enumerate(frames), key=rank)]
    lanes = max(1, min(int(lanes), len(ordered)))
    if lanes == 1:
        return ordered
    runs = [list(run) for run in np.array_split(np.arange(len(ordered)), lanes)]
    turns = [ordered[run[k]] for k in range(len(runs[0])) for run in runs if k < len(run)]
    return turns


def _shared_tilts(config: LibraryConfig, batch: BatchSettings | None, n_frames: int,
                  out: Path) -> LibraryConfig:
    """``config`` with the tilts solved once by the driver on the stage's local workers
    (:mod:`holofit.library.tilts`), where the frames run on at least two local worker
    processes; else as it is (each worker solves the tilts it needs). An engine that serves
    every orientation from its own T-matrix (``exact``, ``cluster``) has nothing to share:
    each worker solves once and rotates, without the spawned processes' start-up."""
    opts = batch or BatchSettings()
    workers = _local_workers(opts, n_frames)
    if opts.scheduler or opts.dask_local or workers < 2:
        return config
    if getattr(config.particle.theory(config.engine), "own_tmatrix", False):
        return config
    path = out / TILTS_FILE
    n_tilts = len(tilt_grid(config.particle.model, math.radians(config.settings.tilt_step_deg)))
    probe = new_library(config)
    if not (path.exists() and load_tilts(probe, path, config.key())):
        if solve_tilts(partial(new_library, config), config.key(), n_tilts, workers,
                       path) is None:
            return config
    return replace(config, tilts=str(path))


def _local_workers(batch: BatchSettings | None, n_frames: int) -> int:
    """The local worker processes the stage's frames run on (at least one)."""
    opts = batch or BatchSettings()
    workers = opts.workers if opts.workers is not None else available_cpus()
    return max(1, min(workers, n_frames))


def _load(loader: FrameLoader, frame: int) -> LibraryPayload | Precomputed:
    """The shared loader's frame as the library's payload."""
    got = loader(frame)
    if isinstance(got, Precomputed):
        return got
    return LibraryPayload(got.crop, got.corner, got.start)


def _library_table(config: LibraryConfig, crops: CropSet, prefit: Path,
                   out: Path) -> StageTable:
    """``library.csv``: columns and units (:mod:`holofit.tables.library`), sidecar,
    fingerprint."""
    s = config.settings
    tilts = tilt_grid(config.particle.model, math.radians(s.tilt_step_deg))
    meta = sidecar(
        kind="orientation library (candidate starts per frame)",
        units={"particle": "track id (crops of several tracks)",
               **library_units(s.n_candidates)},
        config=config.as_dict(),
        inputs=[crops.table_path, prefit],
        extra={"crops": crops.fingerprint(), "particle_model": config.particle.model.kind,
               "tilts_rad": [[t.theta, t.phi] for t in tilts]},
    )
    return StageTable(out / "library.csv",
                      keyed_columns(library_columns(s.n_candidates), crops.key_columns), meta,
                      fingerprint({"config": config.as_dict(), "crops": crops.fingerprint()}),
                      "library", key_columns=crops.key_columns)
