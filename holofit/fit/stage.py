"""``holofit fit``: the DDA fit of every frame of every track (the paper's steps 5-6).

- **Initial pass** (``initial.csv``): every parameter free (position, orientation, alpha and
  the particle's static parameters: a rod's a, b, n; a Janus particle's core radius, cap
  thickness and both indices; a dimer's radii, gap and indices) on some frames of each track:
  spread over the movie, each seeded from the start statics' T-matrix, where the particle has
  one (:mod:`holofit.fit.seeded`), else the first ones. Each track's robust average of its
  ``ok`` rows goes to ``static.json`` (:mod:`holofit.fit.static`; ``pooled``: one average).
- **Final pass** (``fit.csv``): each track's static parameters fixed, position, orientation
  and alpha fitted on every frame; for an anisotropic particle the pass follows each track
  (:mod:`holofit.fit.follow`), with independent frames (``--independent-frames``) each
  frame from the library's starts; then the continuity sweeps (:mod:`holofit.fit.sweeps`).
- Where another track's hologram overlaps a crop, the row is refitted with that neighbour's
  field (:mod:`holofit.fit.overlaps`).

Every table is keyed by ``(particle, frame)``; a track is a group of keys. The passes
(:mod:`holofit.fit.passes`) are batches of the stage skeleton (:mod:`holofit.batch.stage`:
parallel, resumable, failures recorded); the tables follow the fit-table schema
(:mod:`holofit.tables.fit`), which ``holofit analyze`` reads as it is.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

from threadpoolctl import threadpool_limits

from holofit.batch import BatchSettings
from holofit.batch.stage import FrameLoader, StageInputs, stage_inputs
from holofit.config import ParticleConfig
from holofit.fit.config import PASSES, FitConfig, FitRun
from holofit.fit.errors import FitStageError
from holofit.fit.final_pass import final_pass
from holofit.fit.initial_pass import initial_pass
from holofit.fit.passes import FitPasses
from holofit.fit.task import check_fixed
from holofit.fit.tmatrix_policy import check_policy
from holofit.tables.inputs import StageInputError, read_stage_table

__all__ = ["PASSES", "FitConfig", "FitRun", "FitStageError", "run_fit"]


def run_fit(crop_dir: str | Path, prefit: str | Path, library: str | Path | None,
            out_dir: str | Path, config: FitConfig, *,
            batch: BatchSettings | None = None) -> FitRun:
    """The DDA fit of every track of a crop folder (see the module docstring).

    Parameters
    ----------
    crop_dir, prefit : str or Path
        Outputs of ``holofit crop`` and of ``holofit prefit`` for these crops (start
        positions and alpha).
    library : str or Path, optional
        Output of ``holofit library`` for these crops and this particle (start orientations);
        not needed for an isotropic particle.
    out_dir : str or Path
        Where ``initial.csv``, ``static.json``, ``fit.csv`` (each with a sidecar), the plots
        and the frame pictures go.
    config : FitConfig
        What is fitted and how.
    batch : BatchSettings, optional
        Parallel backend and resumption.

    Raises
    ------
    CropSetError, StageInputError, ConfigError, ValueError, FitStageError
        With the file, frame or parameter at fault.
    """
    check_fixed(config.particle.model, tuple(config.fixed))
    check_policy(config.tmatrix, config.particle, config.engine,
                 final_pass=config.passes != "initial")
    run = FitRun()
    # this process on one BLAS thread, as the workers are: OpenBLAS's pool spends several
    # times the CPU on the small dense solves of a T-matrix build and the in-memory refits
    with threadpool_limits(limits=1, user_api="blas"), stage_inputs(
            crop_dir, None if config.frames is None else list(config.frames),
            config.instrument, config.override_instrument, config.numerical_aperture,
            config.fit_na) as given:
        given = replace(given, frames=_chosen_tracks(given, config))
        passes = _open(given, config, Path(prefit), None if library is None else Path(library),
                       Path(out_dir), run, batch)
        static_path = (Path(config.static) if config.static is not None
                       else passes.out / "static.json")
        if config.passes in ("initial", "both"):
            run.static = initial_pass(passes)
            static_path = run.static if config.static is None else static_path
        if config.passes in ("final", "both"):
            final_pass(passes, static_path)
    return run


def _chosen_tracks(given: StageInputs, config: FitConfig) -> list[tuple[int, int]]:
    """The keys of the tracks asked for (``particles``, less ``exclude_particles``).

    Raises
    ------
    FitStageError
        A track asked for that the crops do not have, or none left.
    """
    have = sorted({int(k[0]) for k in given.frames})
    asked = set(have if config.particles is None else config.particles)
    unknown = sorted((asked | set(config.exclude_particles)) - set(have))
    if unknown:
        raise FitStageError(f"{given.crops.table_path}: no track(s) {unknown} (tracks: "
                            f"{', '.join(map(str, have))})")
    keep = asked - set(config.exclude_particles)
    if not keep:
        raise FitStageError("--particle / --exclude-particle leave no track to fit")
    return [k for k in given.frames if int(k[0]) in keep]


def _open(given: Any, config: FitConfig, prefit: Path, library: Path | None, out: Path,
          run: FitRun, batch: BatchSettings | None) -> FitPasses:
    """Read the prefit's and the library's tables (checked against the crops and the
    particle) into the shared frame loader."""
    crops = given.crops
    # one lattice for both passes, whatever the fitted index does to the dipole rule
    particle = config.particle.with_fixed_lattice(given.instrument.optics)
    pre, _ = read_stage_table(prefit, crops, "prefit")
    lib_table = None
    if particle.model.anisotropic:
        if library is None:
            raise StageInputError(f"a {particle.model.kind} needs starting orientations: "
                                  "give the output of `holofit library` (--library)")
        lib_table, lib_meta = read_stage_table(library, crops, "library")
        _check_library(lib_meta, particle, library)
    loader = FrameLoader(crops, pre, lib_table)
    inputs = [crops.table_path, prefit, *([library] if library else [])]
    out.mkdir(parents=True, exist_ok=True)
    return FitPasses(given, config, particle, loader, inputs, out, run, batch)


def _check_library(meta: dict[str, Any], particle: ParticleConfig, path: Path) -> None:
    lib = meta.get("config", {}).get("particle")
    if not isinstance(lib, dict):
        return
    mine = particle.as_dict()
    if lib.get("model") != mine["model"]:
        raise StageInputError(f"{path}: library made for a {lib.get('model')!r}, but "
                              f"{particle.path or 'the particle'} is a {mine['model']!r}")
    diff = [k for k in mine.items() if k[0] not in ("settings", "path")
            and k[0] in lib and lib.get(k[0]) != k[1]]
    if diff:
        detail = ", ".join(f"{k} {lib[k]} vs {v}" for k, v in diff)
        raise StageInputError(
            f"{path}: library made for another {mine['model']} ({detail}): rerun "
            "`holofit library` with this particle config")
