"""The model error of a fit table: how far the engine's own discretisation moves the fit.

A fit's error bars (``d_*``) are its statistics: they say nothing of the model's own error, and
the DDA's at its default rule (about ten dipoles per wavelength) is larger than them wherever
it has been measured against an exact solution (``docs/validation/dda.md``). So every fit table
says how large it is, in its sidecar (``fit.csv.json``, ``model_error``) and in the stage's
notes:

* **a discrete-dipole engine** (``builtin``, ``adda``): a few frames spread over the tracks
  (:data:`MODEL_ERROR_FRAMES`, frames of the initial pass where they have an ``ok`` row there:
  its fit is the default rule's with every parameter free, the natural start) are fitted
  again with every parameter free, at the run's lattice and at a lattice :data:`REFINE`
  times finer, from the same start and on the same pixels (so that the camera noise enters
  both fits alike and their difference is the model's). The DDA's error falls about as the
  dipole size ``d`` (first order: measured for shells, spheroids and, a little faster, rods),
  so with ``p(d) = p* + C d`` the change ``p(d) - p(d / r)`` is ``(1 - 1/r) C d``
  (:func:`estimate_model_error`) and its first-order extrapolation ``change / (1 - 1/r)`` the
  estimate. Read it as a size of the model error, not a signed correction: a
  lattice's staircase changes irregularly with ``d``, and the extrapolation multiplies that
  too. Against exact fits of the same frames (a rod made by its exact T-matrix,
  ``tests/test_fit_exact.py``) it overstated the DDA's error of the lengths 1.6-8 times, but
  had the wrong sign for the index and, with the plane-fraction filling, 0.6 times its size:
  not a bound of the index's error. Finer rather
  than coarser, though it costs ``r^3`` times the run's solves on those frames: one step
  coarser the lattice leaves the convergent regime where the default is near its edge (a thin
  shell two dipoles thick is then one), and the change there has the wrong sign (measured on
  an exact coated-sphere hologram, ``tests/test_model_error.py``). A voxel file's lattice is its
  shape: it is not estimated.
* **an exact engine**: the T-matrix build's stated accuracy (``truncation_estimate``,
  tolerance, order, method: the provenance of its build; :func:`exact_accuracy`) - a far-field
  accuracy, relative to the largest amplitude, not a change of parameters.

:func:`estimate_model_error` is the pure rule; :func:`model_error_entry` is the stage's hook
(a batch of its own, ``OUT/model_error.csv``: parallel, resumable).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import pandas as pd

from holofit.batch.stage import StageTable, fingerprint, run_stage
from holofit.config import ParticleConfig
from holofit.dda.settings import DDA_ENGINES
from holofit.fit.problem import FrameProblem, state_of
from holofit.fit.task import PassConfig, free_parameters, item_theory
from holofit.fit.tmatrix_policy import tmatrix_builder
from holofit.fit.warm import fit_frame_warm
from holofit.holomodel.parameters import static_parameters, static_values
from holofit.particles import VoxelShape
from holofit.provenance import sidecar
from holofit.status import OK, POOR_FIT
from holofit.tables.cropset import PARTICLE_KEY

__all__ = [
    "ASSUMED_ORDER",
    "MODEL_ERROR_FRAMES",
    "REFINE",
    "ModelErrorSettings",
    "choose_frames",
    "estimate_model_error",
    "exact_accuracy",
    "model_error_entry",
    "model_error_note",
]

#: frames refitted for a DDA table's estimate
MODEL_ERROR_FRAMES = 3
#: the other lattice is this many times finer than the run's (module docstring)
REFINE = 1.25
#: the assumed order of the DDA's convergence in the dipole size
ASSUMED_ORDER = 1.0


@dataclass(frozen=True)
class ModelErrorSettings:
    """Whether and how a fit table's model error is estimated (:mod:`holofit.fit.model_error`).

    Attributes
    ----------
    enabled : bool, optional
        None: on for the discrete-dipole engines (their refits), and the exact engines' stated
        accuracy recorded; False: neither (``--no-model-error``).
    frames : int
        Frames refitted for a DDA table (spread over the tracks).
    refine : float
        The run's dipole size over the other lattice's (> 1: finer).
    """

    enabled: bool | None = None
    frames: int = MODEL_ERROR_FRAMES
    refine: float = REFINE

    def __post_init__(self) -> None:
        if self.frames < 1:
            raise ValueError(f"model-error frames must be >= 1, got {self.frames}")
        if not self.refine > 1.0:
            raise ValueError(f"model-error refine must be > 1 (a finer lattice), got "
                             f"{self.refine}")


def choose_frames(keys: list[tuple[int, int]], n: int) -> list[tuple[int, int]]:
    """``n`` of ``keys`` (sorted), evenly spread: the middle one of each of ``n`` equal runs."""
    keys = sorted(keys)
    if len(keys) <= n:
        return keys
    return [keys[(2 * i + 1) * len(keys) // (2 * n)] for i in range(n)]


def estimate_model_error(default: pd.DataFrame, finer: pd.DataFrame, names: list[str],
                         refine: float, order: float = ASSUMED_ORDER) -> dict[str, Any]:
    """The default rule's error of each parameter from fits at two dipole sizes.

    With ``p(d) = p* + C d^order`` (the DDA's convergence), fits at ``d`` and ``d / refine``
    differ by ``(1 - refine^-order) C d^order``, the default's own error ``C d^order`` times
    ``1 - refine^-order``; so the estimate is the mean change over the frames divided by that.

    Parameters
    ----------
    default, finer : DataFrame
        One row per frame, same order: each parameter's value (and ``d_<name>``, its
        1-sigma error, in ``default``) at the run's dipole size and at ``1 / refine`` of it.
    names : list of str
        The parameters (columns).
    refine : float
        The default dipole size over the finer one (> 1).
    order : float
        The assumed convergence order in ``d``.

    Returns
    -------
    dict
        Per parameter: ``changes`` (default - finer, per frame: a lower bound of the
        default's error only where the fits converge monotonically, which a lattice's
        staircase need not), ``change_mean``, ``change_sd`` (their spread; NaN for one
        frame), ``estimate`` (of the default's offset from the limit ``d -> 0``; its size is
        the model error's scale, its sign unreliable: module docstring), ``sigma`` (median
        statistical error of the default fits) and ``estimate_over_sigma``.
    """
    scale = 1.0 - refine ** (-order)
    out: dict[str, Any] = {}
    for name in names:
        a = default[name].to_numpy(dtype=float)
        b = finer[name].to_numpy(dtype=float)
        change = a - b
        ok = np.isfinite(change)
        if not ok.any():
            continue
        mean = float(np.mean(change[ok]))
        sd = float(np.std(change[ok], ddof=1)) if ok.sum() > 1 else math.nan
        err = f"d_{name}"
        sigma = (float(np.nanmedian(default[err].to_numpy(dtype=float)))
                 if err in default else math.nan)
        estimate = mean / scale
        out[name] = {"changes": [float(c) for c in change], "change_mean": mean,
                     "change_sd": sd, "estimate": estimate, "sigma": sigma,
                     "estimate_over_sigma": (estimate / sigma if sigma > 0 else math.nan)}
    return out


def exact_accuracy(provenance: dict[str, Any]) -> dict[str, Any]:
    """An exact T-matrix's stated accuracy from its build's provenance: the method, order,
    truncation estimate (far-field change between orders ``L - 4`` and ``L``, relative to
    the largest amplitude), the tolerance aimed at and whether it was met."""
    keys = ("method", "order", "truncation_estimate", "tolerance", "tolerance_met",
            "order_search_stop", "truncation_estimate_of")
    doc = {k: provenance[k] for k in keys if k in provenance}
    doc["kind"] = "exact T-matrix: build's stated far-field accuracy"
    doc["relative_to"] = "the largest far-field amplitude"
    return doc


@dataclass(frozen=True)
class RefitConfig:
    """What a worker needs for the model-error refits (picklable)."""

    passes: PassConfig
    refine: float

    def as_dict(self) -> dict[str, Any]:
        return {"pass": self.passes.as_dict(), "refine": self.refine}


@dataclass(frozen=True)
class RefitPayload:
    """One frame's crop and start (the values of its initial or final row)."""

    crop: np.ndarray
    corner: tuple[int, int]
    start: dict[str, float]


def finer_particle(particle: ParticleConfig, refine: float) -> ParticleConfig:
    """``particle`` on a lattice ``refine`` times finer (its ``[dda]`` dipole size, which the
    fit stage has written out, over ``refine``)."""
    table = dict(particle.settings.get("dda", {}))
    d = table.get("dipole_size_um")
    if d is None:
        raise ValueError(f"{particle.path or 'the particle'}: no fixed dipole size to refine")
    table["dipole_size_um"] = float(d) / refine
    return replace(particle, settings={**particle.settings, "dda": table})


def refit_task(config: RefitConfig, key: tuple[int, int], payload: RefitPayload
               ) -> dict[str, Any]:
    """Fit one frame with every parameter free at the run's lattice and at the finer one,
    from the same start; the item function of the model-error batch."""
    p, f = int(key[0]), int(key[1])
    base = replace(config.passes.for_track(p), tmatrix=None, seed_tmatrix=None)
    inst = base.instrument
    model = base.particle.model
    free = free_parameters(model, "initial", base.fixed, base.fit_na)
    opts = replace(base.options, mirror=False, stop_chi2=0.0)
    row: dict[str, Any] = {"particle": p, "frame": f}
    start = state_of(payload.start, model)
    statuses = []
    for suffix, cfg in (("", base), ("_fine", replace(
            base, particle=finer_particle(base.particle, config.refine)))):
        problem = FrameProblem(payload.crop, payload.corner, inst.pixel_size_um,
                               item_theory(cfg), model, inst.optics, free, opts, seed=f)
        res = fit_frame_warm(problem, start).result
        row.update({f"{name}{suffix}": value for name, value in res.values.items()})
        if not suffix:
            row.update({f"d_{n}": e for n, e in res.errors.items()})
        row[f"chi2_red{suffix}"] = res.chi2_red
        statuses.append(res.status)
    row["status_fine"] = statuses[1]
    both = all(st == OK for st in statuses)
    row["status"] = OK if both else POOR_FIT
    row["message"] = "" if both else f"default rule {statuses[0]}, finer {statuses[1]}"
    return row


def model_error_note(entry: dict[str, Any]) -> str:
    """The sidecar entry in one line (the stage's notes)."""
    if entry.get("kind", "").startswith("exact"):
        return (f"model error: exact engine, T-matrix {entry.get('method')} at order "
                f"{entry.get('order')}, stated far-field accuracy "
                f"{float(entry.get('truncation_estimate', math.nan)):.1e} (truncation estimate)")
    if "parameters" not in entry:
        return f"model error: {entry.get('reason', 'not estimated')}"
    params = entry["parameters"]
    ranked = sorted(params.items(), key=lambda kv: -abs(kv[1]["estimate_over_sigma"])
                    if math.isfinite(kv[1]["estimate_over_sigma"]) else 0.0)
    text = ", ".join(f"{k} ~{abs(v['estimate']):.2g} ({abs(v['estimate_over_sigma']):.1f} "
                     "sigma)" for k, v in ranked[:6])
    return (f"model error of the DDA at its rule (d = {entry['dipole_size_um'] * 1e3:.1f} nm; "
            f"{len(entry['frames'])} frame(s) refitted with dipoles {entry['refine']:g}x "
            f"smaller, first-order extrapolation; a size, not a signed correction): {text}")


def model_error_entry(fp: Any, table: pd.DataFrame, cfg: PassConfig,
                      settings: ModelErrorSettings) -> dict[str, Any] | None:
    """The final table's model-error entry (module docstring), or None when switched off.

    Parameters
    ----------
    fp : FitPasses
        The stage's passes (inputs, output folder, batch options).
    table : DataFrame
        The final pass's rows.
    cfg : PassConfig
        The final pass's config (each track's statics).
    settings : ModelErrorSettings
        Whether, and how many frames.
    """
    if settings.enabled is False:
        return None
    theory = cfg.particle.theory(cfg.engine)
    if theory.name not in DDA_ENGINES:
        if getattr(theory, "fix_discretisation", None) is None:
            return {"kind": f"exact series ({theory.name})",
                    "reason": f"the {theory.name} engine's series is exact to its truncation"}
        theory = cfg.particle.theory(cfg.engine, fixed_lattice_for=cfg.instrument.optics)
        build = tmatrix_builder(theory)
        return exact_accuracy(build(cfg.particle.model, cfg.instrument.optics).provenance)
    if isinstance(cfg.particle.model, VoxelShape):
        return {"kind": "not estimated",
                "reason": "a voxel file's lattice is its shape: no other rule to compare"}
    return _dda_entry(fp, table, cfg, settings)


def _dda_entry(fp: Any, table: pd.DataFrame, cfg: PassConfig,
               settings: ModelErrorSettings) -> dict[str, Any]:
    """The DDA refits' batch and their estimate."""
    model = cfg.particle.model
    mine = table[(table["model"] == model.kind) & (table["status"] == OK)]
    initial = _initial_rows(fp.out / "initial.csv", model.kind)
    keys = [(int(p), int(f)) for p, f in zip(mine["particle"], mine["frame"], strict=True)]
    with_initial = [k for k in keys if k in initial]
    frames = choose_frames(with_initial or keys, settings.frames)
    if not frames:
        return {"kind": "not estimated", "reason": "no ok row to refit"}
    rows = {(int(r["particle"]), int(r["frame"])): r for _, r in mine.iterrows()}
    starts = {k: initial.get(k) or _final_start(rows[k], cfg) for k in frames}
    config = RefitConfig(cfg, settings.refine)
    free = free_parameters(model, "initial", cfg.fixed, cfg.fit_na)
    crops = fp.given.crops

    def load(key: tuple[int, int]) -> RefitPayload:
        crow = crops.row(key)
        return RefitPayload(crops.crop(key), (int(crow["corner_row"]), int(crow["corner_col"])),
                            starts[key])

    params = _parameters(model, free)
    columns = ("particle", "frame", *params, *(f"d_{n}" for n in params),
               *(f"{n}_fine" for n in params), "chi2_red", "chi2_red_fine",
               "status_fine", "fit_time_s", "status", "message")
    key = fingerprint({"config": config.as_dict(), "crops": crops.fingerprint(),
                       "starts": {f"{k[0]},{k[1]}": {n: float(f"{v:.10g}") for n, v in
                                                     sorted(s.items())}
                                  for k, s in sorted(starts.items())}})
    meta = sidecar(kind="model-error refits: every parameter free at the run's lattice and "
                        f"at a {settings.refine:g}x finer one", config=config.as_dict(),
                   inputs=[crops.table_path])
    out = fp.out / "model_error.csv"
    stage_table = StageTable(out, columns, meta, key, "fit (model error)",
                             key_columns=PARTICLE_KEY, replace_stale=True)
    summary, _ = run_stage(refit_task, config, frames, load, stage_table, batch=fp.batch)
    fp.run.summaries["model error"] = summary
    done = pd.read_csv(out)
    done = done[done["status"] == OK]
    d0 = float(cfg.particle.settings["dda"]["dipole_size_um"])
    entry: dict[str, Any] = {
        "kind": "DDA rule change", "engine": cfg.engine or "auto", "dipole_size_um": d0,
        "fine_dipole_size_um": d0 / settings.refine, "refine": settings.refine,
        "assumed_order": ASSUMED_ORDER, "table": str(out),
        "frames": [[int(p), int(f)] for p, f in zip(done["particle"], done["frame"],
                                                    strict=True)],
        "rule": "estimate = (p(default) - p(fine)) / (1 - refine^-order): the default rule's "
                "offset from the d -> 0 limit, assuming p(d) = p* + C d^order; a "
                "size of the model error, not a signed correction (against exact fits of the "
                "same frames it overstated the lengths' error 1.6-8x, and gave the index's "
                "the wrong sign at 0.6x its size)"}
    if done.empty:
        entry["reason"] = "no refit ended ok"
        return entry
    names = [n for n in params if n in done.columns and f"{n}_fine" in done.columns]
    fine = done[[f"{n}_fine" for n in names]].set_axis(names, axis=1)
    entry["parameters"] = estimate_model_error(done, fine, names, settings.refine)
    return entry


def _parameters(model: Any, free: tuple[str, ...]) -> list[str]:
    """The refits' reported columns: position, orientation angles, alpha, the statics."""
    orient = []
    if model.anisotropic:
        orient = ["theta_rad", "psi_rad", *([] if model.axisymmetric else ["phi_rad"]),
                  "ux", "uy", "uz"]
    statics = [p.name for p in static_parameters(model) if p.name in free]
    return ["x_um", "y_um", "z_um", *orient, "alpha", *statics]


def _initial_rows(path: Any, kind: str) -> dict[tuple[int, int], dict[str, float]]:
    """The ok rows of ``initial.csv`` of the model ``kind`` as starts (none if absent)."""
    try:
        table = pd.read_csv(path)
    except (FileNotFoundError, pd.errors.EmptyDataError):
        return {}
    table = table[(table["status"] == OK) & (table.get("model", kind) == kind)]
    out = {}
    for _, r in table.iterrows():
        out[(int(r["particle"]), int(r["frame"]))] = _numeric(r)
    return out


def _final_start(row: pd.Series, cfg: PassConfig) -> dict[str, float]:
    """A final row's values with its track's statics (no initial row at that frame)."""
    values = _numeric(row)
    for name, v in static_values(cfg.for_track(int(row["particle"])).particle.model):
        values.setdefault(name, v)
    return values


def _numeric(row: pd.Series) -> dict[str, float]:
    return {k: float(v) for k, v in row.items()
            if isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool)
            and np.isfinite(v)}
