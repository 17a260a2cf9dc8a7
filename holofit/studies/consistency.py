"""Calibration of the physical-consistency check (:mod:`holofit.analysis.consistency`).

* :func:`false_flag_case` - honest Brownian tracks of the calibration study's particles
  (:func:`holofit.studies.diffusion.calibration_trajectory`: the paper's rod sinking 0.9 um/s,
  its Janus sphere, a sphere of the same size) whose optical sizes are the ones their
  coefficients follow from: the fraction flagged (the check's false-flag rate, ``alpha`` =
  1 % by default) and each test's rate of p-values below 1 %, 5 % and its per-test threshold.
* :func:`sticking_sphere` and :func:`sticking_case` - a 500 nm sphere that sticks to the
  surface for a stretch of its track (its true position held, the localisation noise kept):
  the fraction flagged (the check's power), and which tests found it.
* :func:`rotation_off_rod` and :func:`rotation_case` - the calibration study's rod whose
  rotational diffusion is a factor off the spherocylinder of its optical size (0.6: a rod
  that drags on the surface, or one larger than its fit says; 1: the clean rod), its
  translation unchanged: the fraction flagged, and by the rotational size test alone (its
  power, or at factor 1 its false-flag rate).
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from holofit.analysis.hydrodynamics import sphere_diffusion
from holofit.analysis.pipeline import analyze_trajectory
from holofit.analysis.results import AnalysisResult
from holofit.analysis.settings import AnalysisConfig
from holofit.analysis.trajectory import Trajectory
from holofit.conventions import rotation_from_vector
from holofit.simulate.brownian import BrownianParameters, propagate_rigid_body
from holofit.studies.diffusion import (
    CALIBRATION_DT,
    CALIBRATION_DYNAMICS,
    CALIBRATION_NOISE,
    CALIBRATION_T_C,
    calibration_trajectory,
)

__all__ = [
    "OPTICAL_SIZES",
    "FlagSummary",
    "false_flag_case",
    "rotation_case",
    "rotation_off_rod",
    "sticking_case",
    "sticking_sphere",
]

#: the optical sizes that go with the calibration study's dynamics, um (the paper's rod, a
#: 501 nm, b 1079 nm, whose spherocylinder D_t 0.297 and D_r 0.311 match its 0.2977 and
#: 0.311; the Janus sphere's 524 nm hydrodynamic radius)
OPTICAL_SIZES = {"rod": {"a_um": 0.501, "b_um": 1.079}, "janus": {"radius_um": 0.524},
                 "sphere": {"radius_um": 0.524}}
#: per-frame spread of a fitted size in the simulated tables, um (its standard error over
#: N frames is this over sqrt(N))
SIZE_SPREAD_UM = 0.01


def _with_sizes(traj: Trajectory, sizes: dict[str, float], n_frames: int) -> Trajectory:
    traj.static = {k: {"median": v, "std": SIZE_SPREAD_UM, "count": n_frames, "held": 0}
                   for k, v in sizes.items()}
    return traj


@dataclass
class FlagSummary:
    """How often the check flagged the tracks of one case, and why.

    Attributes
    ----------
    case : dict
        What was simulated (model, noise, frames, ...).
    n : int
        Tracks analysed.
    flagged : int
        Tracks flagged.
    failed_by_test : Counter
        Test name -> tracks it failed (a track may fail several).
    p_values : dict
        Test name -> the p-values of the tracks where it ran.
    thresholds : list of float
        Each track's per-test threshold ``alpha / m``.
    errors : int
        Tracks whose analysis failed (too short to analyse).
    """

    case: dict[str, Any]
    n: int = 0
    flagged: int = 0
    failed_by_test: Counter = field(default_factory=Counter)
    p_values: dict[str, list[float]] = field(default_factory=dict)
    thresholds: list[float] = field(default_factory=list)
    errors: int = 0

    def add(self, res: AnalysisResult) -> None:
        """Count one analysed track."""
        c = res.consistency
        assert c is not None
        self.n += 1
        self.flagged += int(c.flagged)
        self.failed_by_test.update(c.failed)
        self.thresholds.append(c.threshold)
        for t in c.tests:
            if math.isfinite(t.p_value):
                self.p_values.setdefault(t.name, []).append(t.p_value)

    @property
    def rate(self) -> float:
        """Fraction flagged."""
        return self.flagged / self.n if self.n else math.nan

    @property
    def rate_error(self) -> float:
        """Binomial standard error of :attr:`rate` (at least that of one track in ``n``)."""
        if not self.n:
            return math.nan
        p = max(self.rate, 1.0 / self.n)
        return math.sqrt(p * (1 - p) / self.n)

    def rows(self) -> list[dict[str, Any]]:
        """Flat rows: one for the case, one per test."""
        out = [{**self.case, "test": "any (flagged)", "n": self.n, "errors": self.errors,
                "rate": self.rate, "rate_err": self.rate_error}]
        thr = float(np.median(self.thresholds)) if self.thresholds else math.nan
        for name, ps in self.p_values.items():
            p = np.asarray(ps)
            out.append({**self.case, "test": name, "n": int(p.size), "threshold": thr,
                        "failed": int(self.failed_by_test.get(name, 0)),
                        "below_threshold": float(np.mean(p < thr)),
                        "below_0.01": float(np.mean(p < 0.01)),
                        "below_0.05": float(np.mean(p < 0.05))})
        return out


def false_flag_case(model: str, noise: str, n_frames: int, n_seeds: int, first_seed: int = 0,
                    settings: AnalysisConfig | None = None) -> FlagSummary:
    """The check on ``n_seeds`` honest tracks of the calibration study (module docstring)."""
    settings = settings or AnalysisConfig(model, temperature_c=CALIBRATION_T_C)
    out = FlagSummary({"model": model, "noise": noise, "frames": n_frames})
    for i in range(n_seeds):
        seed = 7_000_000 + 1_000_000 * ("rod", "janus", "sphere").index(model) \
            + 100 * n_frames + first_seed + i
        traj = _with_sizes(calibration_trajectory(model, noise, n_frames, seed),
                           OPTICAL_SIZES[model], n_frames)
        try:
            out.add(analyze_trajectory(traj, settings))
        except ValueError:  # AnalysisError: too short to analyse
            out.errors += 1
    return out


def sticking_sphere(seed: int, n_frames: int = 150, stuck: tuple[int, int] | None = (50, 100),
                    radius_um: float = 0.5, eps_um: float = 0.002,
                    temperature_c: float = CALIBRATION_T_C) -> tuple[Trajectory, float]:
    """A Stokes-Einstein sphere at 100 frames/s that sticks during frames ``stuck``
    (``[first, last)``: its true position held, the measurement noise ``eps_um`` on each
    coordinate kept); its fit table's radius is the true one.

    Returns
    -------
    Trajectory, float
        The measured track and its free diffusion coefficient, um^2/s.
    """
    d = sphere_diffusion(radius_um, temperature_c)["D_t"]
    dt = 0.01
    rng = np.random.default_rng(seed)
    steps = rng.standard_normal((n_frames - 1, 3)) * math.sqrt(2 * d * dt)
    if stuck is not None:
        steps[stuck[0]:stuck[1] - 1] = 0.0
    pos = np.concatenate([np.zeros((1, 3)), np.cumsum(steps, axis=0)])
    pos += eps_um * rng.standard_normal(pos.shape)
    traj = Trajectory.from_arrays(pos, None, dt, source=f"sticking sphere seed {seed}")
    return _with_sizes(traj, {"radius_um": radius_um}, n_frames), d


def sticking_case(n_seeds: int, n_frames: int = 150, stuck: tuple[int, int] | None = (50, 100),
                  eps_um: float = 0.002, first_seed: int = 0) -> tuple[FlagSummary, list[float]]:
    """The check on ``n_seeds`` sticking spheres (:func:`sticking_sphere`); also returns their
    measured ``D_t`` (the free sphere's is 0.440 um^2/s at 21 C)."""
    out = FlagSummary({"model": "sphere", "frames": n_frames, "stuck": str(stuck),
                       "eps_nm": 1e3 * eps_um})
    values = []
    settings = AnalysisConfig("sphere", temperature_c=CALIBRATION_T_C)
    for i in range(n_seeds):
        traj, _ = sticking_sphere(900_000 + first_seed + i, n_frames, stuck, eps_um=eps_um)
        res = analyze_trajectory(traj, settings)
        out.add(res)
        values.append(res.measured["D_t"].value)
    return out, values


def rotation_off_rod(seed: int, n_frames: int, factor: float, noise: str = "replicate"
                     ) -> Trajectory:
    """The calibration study's rod (the paper's rod sinking 0.9 um/s, 100 frames/s,
    :func:`holofit.studies.diffusion.calibration_trajectory`'s noise) whose D_r is ``factor``
    times the paper's 0.311 1/s, its D_par, D_perp unchanged, with the optical sizes of the
    paper's rod (:data:`OPTICAL_SIZES`): the spherocylinder of the fitted a, b predicts D_r
    0.311 1/s whatever ``factor`` is."""
    d_par, d_perp, d_r, drift = CALIBRATION_DYNAMICS["rod"]
    eps, eps_r = CALIBRATION_NOISE[noise]
    rng = np.random.default_rng(seed)
    params = BrownianParameters(n_frames, CALIBRATION_DT, d_par, d_perp, factor * d_r,
                                drift_um_s=drift)
    pos, rot = propagate_rigid_body(params, rng)
    pos = pos + eps * rng.standard_normal(pos.shape)
    w = rng.standard_normal((n_frames, 3)) * (eps_r / math.sqrt(2.0))
    w[:, 2] = 0.0  # a spin about the axis does not move it
    axis = np.einsum("nij,nj->ni", rot, rotation_from_vector(w)[:, :, 2])
    traj = Trajectory.from_arrays(pos, axis, CALIBRATION_DT,
                                  source=f"rod D_r x {factor:g} seed {seed}")
    return _with_sizes(traj, OPTICAL_SIZES["rod"], n_frames)


def rotation_case(n_seeds: int, n_frames: int, factor: float, noise: str = "replicate",
                  first_seed: int = 0, settings: AnalysisConfig | None = None
                  ) -> tuple[FlagSummary, list[float]]:
    """The check on ``n_seeds`` rods of :func:`rotation_off_rod`; also returns each track's
    rotational size statistic ``z`` (NaN where that test did not run).

    Seeds ``20_000_000 + 10_000 * round(100 * factor) + 100 * n_frames + first_seed + i``:
    apart from :func:`false_flag_case`'s."""
    settings = settings or AnalysisConfig("rod", temperature_c=CALIBRATION_T_C)
    out = FlagSummary({"model": "rod", "noise": noise, "frames": n_frames,
                       "d_r_factor": factor})
    z: list[float] = []
    for i in range(n_seeds):
        seed = 20_000_000 + 10_000 * round(100 * factor) + 100 * n_frames + first_seed + i
        try:
            res = analyze_trajectory(rotation_off_rod(seed, n_frames, factor, noise), settings)
        except ValueError:  # AnalysisError: too short to analyse
            out.errors += 1
            continue
        out.add(res)
        c = res.consistency
        t = c.test("size D_r") if c is not None else None
        z.append(t.statistic if t is not None else math.nan)
    return out, z
