"""Rigid-body Brownian trajectories with known truth, written as fit tables.

Dynamics (body frame = particle frame, symmetry axis along body z):

* translation: each (sub)step adds ``R (sqrt(2 D_perp h) g_x, sqrt(2 D_perp h) g_y,
  sqrt(2 D_par h) g_z) + v h`` with ``g`` standard normal, ``R`` the orientation at the start of
  the step and ``v`` an optional drift (sedimentation);
* rotation (Beard & Schlick, Biophys. J. 85, 2973, 2003): a rotation vector
  ``w = (sqrt(2 D_r h) g_1, sqrt(2 D_r h) g_2, sqrt(2 D_spin h) g_3)`` in the body frame, applied
  as the exact finite rotation ``R <- R exp([w]_x)`` (Rodrigues' formula).

``substeps`` steps of ``h = dt / substeps`` per frame resolve the coupling between rotation and
anisotropic translation within a frame. The Gaussian rotation vector is first-order accurate: the
axis correlation after one step is ``1/3 + 2/3 (1 - 2x) exp(-x)`` (``x = D h``) instead of
``exp(-2x)``, an effective ``D (1 + x/6)``; by default the substeps keep ``D h <= 1e-3`` (bias
below 0.02 %).

Measurement model, per frame: Gaussian localisation noise (``eps_xy`` on x and y, ``eps_z`` on
z, um); angular noise as a random body-frame rotation whose two components perpendicular to the
axis have standard deviation ``eps_r / sqrt(2)`` each, so that the angle between measured and
true axis has rms ``eps_r`` (the paper's ``2 eps_r^2`` intercept); optional injected artefacts:
head-tail flips (``u -> -u``), orientations mirrored about the x-y plane (``u_z -> -u_z``, the
Levenberg-Marquardt secondary minimum of the paper), failed frames (status ``failed``) and
missing frames (no row).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numba
import numpy as np
import pandas as pd
from numpy.typing import NDArray

from holofit.conventions import euler_zyz, euler_zyz_from_matrix, rotation_from_vector
from holofit.io.tables import write_table
from holofit.provenance import sidecar
from holofit.status import OK
from holofit.tables.fit import FitTable, column_unit, validate_fit_table, write_fit_table

__all__ = [
    "BrownianParameters",
    "MeasurementNoise",
    "SimulatedTrajectory",
    "propagate_rigid_body",
    "random_rotation",
    "simulate_trajectory",
]


#: default largest ``D_r h`` of one integration step
MAX_ROTATION_STEP = 1e-3
MIN_SUBSTEPS = 4
#: integration steps drawn at once (bounds the memory of the random numbers)
CHUNK_STEPS = 1 << 20


@dataclass(frozen=True)
class BrownianParameters:
    """Dynamics of an axisymmetric rigid particle.

    Parameters
    ----------
    n_frames : int
        Number of frames.
    frame_interval_s : float
        Time between frames, s.
    d_par_um2_s, d_perp_um2_s : float
        Translational diffusion coefficients along and across the symmetry axis, um^2/s.
    d_r_s : float
        Rotational diffusion coefficient about axes perpendicular to the symmetry axis, 1/s.
    d_spin_s : float, optional
        Rotational diffusion about the symmetry axis, 1/s (default: ``d_r_s``).
    drift_um_s : tuple of float
        Constant lab-frame velocity (sedimentation, flow), um/s.
    start_position_um : tuple of float
        Position at frame 0, um.
    start_orientation : tuple of float, optional
        ``(psi, theta, phi)`` at frame 0, rad; uniformly random when None.
    substeps : int, optional
        Integration steps per frame; default: enough for ``D h <= 1e-3`` for every rotational
        coefficient, and at least 4.
    """

    n_frames: int
    frame_interval_s: float
    d_par_um2_s: float
    d_perp_um2_s: float
    d_r_s: float
    d_spin_s: float | None = None
    drift_um_s: tuple[float, float, float] = (0.0, 0.0, 0.0)
    start_position_um: tuple[float, float, float] = (0.0, 0.0, 10.0)
    start_orientation: tuple[float, float, float] | None = None
    substeps: int | None = None

    def __post_init__(self) -> None:
        if self.n_frames < 2:
            raise ValueError(f"n_frames must be >= 2, got {self.n_frames}")
        if not self.frame_interval_s > 0:
            raise ValueError(f"frame_interval_s must be > 0 s, got {self.frame_interval_s}")
        for name in ("d_par_um2_s", "d_perp_um2_s", "d_r_s"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        if self.d_spin_s is not None and not self.d_spin_s >= 0:
            raise ValueError(f"d_spin_s must be >= 0, got {self.d_spin_s}")
        if self.substeps is not None and self.substeps < 1:
            raise ValueError(f"substeps must be >= 1, got {self.substeps}")

    @property
    def steps_per_frame(self) -> int:
        """Integration substeps per frame (explicit, or from the ``D h <= 1e-3`` rule)."""
        if self.substeps is not None:
            return int(self.substeps)
        d_max = max(self.d_r_s, self.d_spin_s if self.d_spin_s is not None else 0.0)
        return max(MIN_SUBSTEPS, math.ceil(d_max * self.frame_interval_s / MAX_ROTATION_STEP))


@dataclass(frozen=True)
class MeasurementNoise:
    """Noise and artefacts of the simulated measurement (fractions are of all frames)."""

    eps_xy_um: float = 0.0
    eps_z_um: float | None = None
    eps_r_rad: float = 0.0
    flip_fraction: float = 0.0
    mirror_fraction: float = 0.0
    fail_fraction: float = 0.0
    missing_fraction: float = 0.0

    def __post_init__(self) -> None:
        for name in ("eps_xy_um", "eps_r_rad"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        if self.eps_z_um is not None and not self.eps_z_um >= 0:
            raise ValueError(f"eps_z_um must be >= 0, got {self.eps_z_um}")
        fr = ("flip_fraction", "mirror_fraction", "fail_fraction", "missing_fraction")
        for name in fr:
            if not 0 <= getattr(self, name) < 1:
                raise ValueError(f"{name} must lie in [0, 1), got {getattr(self, name)}")
        if sum(getattr(self, n) for n in fr) >= 1:
            raise ValueError("the artefact fractions add up to 1 or more")


@dataclass
class SimulatedTrajectory:
    """What :func:`simulate_trajectory` produced."""

    table: pd.DataFrame
    truth: pd.DataFrame
    truth_meta: dict[str, Any]
    flipped_frames: NDArray[np.int64]
    mirrored_frames: NDArray[np.int64]
    failed_frames: NDArray[np.int64]
    missing_frames: NDArray[np.int64]
    path: Path | None = None
    truth_path: Path | None = None
    fit: FitTable | None = field(default=None, repr=False)


def random_rotation(rng: np.random.Generator) -> NDArray[np.float64]:
    """A rotation matrix uniformly distributed over SO(3) (from a random unit quaternion)."""
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    a, b, c, d = q
    return np.array(
        [
            [a * a + b * b - c * c - d * d, 2 * (b * c - a * d), 2 * (b * d + a * c)],
            [2 * (b * c + a * d), a * a - b * b + c * c - d * d, 2 * (c * d - a * b)],
            [2 * (b * d - a * c), 2 * (c * d + a * b), a * a - b * b - c * c + d * d],
        ]
    )


@numba.njit(cache=True)
def _propagate(pos, rots, first, last, substeps, h, s_perp, s_par, s_rot, s_spin, drift,
               normals):
    # advances frames first..last-1 from frame first-1 (in place)
    r = pos[first - 1].copy()
    rot = rots[first - 1].copy()
    step = 0
    body = np.empty(3)
    w = np.empty(3)
    exp_w = np.empty((3, 3))
    tmp = np.empty((3, 3))
    for frame in range(first, last):
        for _ in range(substeps):
            g = normals[step]
            body[0] = s_perp * g[0]
            body[1] = s_perp * g[1]
            body[2] = s_par * g[2]
            for i in range(3):
                r[i] += rot[i, 0] * body[0] + rot[i, 1] * body[1] + rot[i, 2] * body[2]
                r[i] += drift[i] * h
            w[0] = s_rot * g[3]
            w[1] = s_rot * g[4]
            w[2] = s_spin * g[5]
            ang = math.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
            if ang > 0.0:
                kx, ky, kz = w[0] / ang, w[1] / ang, w[2] / ang
                sa = math.sin(ang)
                ca = 1.0 - math.cos(ang)
                # exp([k]_x ang) = I + sin(ang) K + (1 - cos(ang)) K^2
                exp_w[0, 0] = 1.0 - ca * (ky * ky + kz * kz)
                exp_w[0, 1] = -sa * kz + ca * kx * ky
                exp_w[0, 2] = sa * ky + ca * kx * kz
                exp_w[1, 0] = sa * kz + ca * kx * ky
                exp_w[1, 1] = 1.0 - ca * (kx * kx + kz * kz)
                exp_w[1, 2] = -sa * kx + ca * ky * kz
                exp_w[2, 0] = -sa * ky + ca * kx * kz
                exp_w[2, 1] = sa * kx + ca * ky * kz
                exp_w[2, 2] = 1.0 - ca * (kx * kx + ky * ky)
                for i in range(3):
                    for j in range(3):
                        tmp[i, j] = (rot[i, 0] * exp_w[0, j] + rot[i, 1] * exp_w[1, j]
                                     + rot[i, 2] * exp_w[2, j])
                rot[:, :] = tmp
            step += 1
        if frame % 256 == 0:
            # re-orthonormalise (Gram-Schmidt on the columns) against round-off drift
            c0 = rot[:, 0] / math.sqrt(np.sum(rot[:, 0] ** 2))
            c1 = rot[:, 1] - np.sum(c0 * rot[:, 1]) * c0
            c1 = c1 / math.sqrt(np.sum(c1**2))
            c2 = np.cross(c0, c1)
            rot[:, 0] = c0
            rot[:, 1] = c1
            rot[:, 2] = c2
        pos[frame] = r
        rots[frame] = rot


def propagate_rigid_body(
    params: BrownianParameters, rng: np.random.Generator
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Integrate the Brownian dynamics.

    Returns
    -------
    position_um : ndarray, shape (n_frames, 3)
    rotation : ndarray, shape (n_frames, 3, 3)
        Particle-to-lab rotation per frame.
    """
    p = params
    if p.start_orientation is None:
        rot0 = random_rotation(rng)
    else:
        rot0 = euler_zyz(*p.start_orientation)
    sub = p.steps_per_frame
    h = p.frame_interval_s / sub
    d_spin = p.d_r_s if p.d_spin_s is None else p.d_spin_s
    pos = np.empty((p.n_frames, 3))
    rots = np.empty((p.n_frames, 3, 3))
    pos[0] = p.start_position_um
    rots[0] = rot0
    frames_per_chunk = max(1, CHUNK_STEPS // sub)
    drift = np.asarray(p.drift_um_s, dtype=float)
    for first in range(1, p.n_frames, frames_per_chunk):
        last = min(first + frames_per_chunk, p.n_frames)
        normals = rng.standard_normal(((last - first) * sub, 6))
        _propagate(
            pos, rots, first, last, sub, h,
            math.sqrt(2 * p.d_perp_um2_s * h),
            math.sqrt(2 * p.d_par_um2_s * h),
            math.sqrt(2 * p.d_r_s * h),
            math.sqrt(2 * d_spin * h),
            drift,
            normals,
        )
    return pos, rots


def _choose(rng: np.random.Generator, pool: NDArray, fraction: float, n: int) -> NDArray:
    k = round(fraction * n)
    if k == 0:
        return np.zeros(0, np.int64)
    chosen = rng.choice(pool, size=min(k, pool.size), replace=False)
    return np.sort(chosen)


def _table(frames, dt, pos, rot, static) -> pd.DataFrame:
    psi, theta, phi = euler_zyz_from_matrix(rot)
    u = rot[:, :, 2]
    df = pd.DataFrame(
        {
            "frame": frames,
            "time_s": frames * dt,
            "x_um": pos[:, 0],
            "y_um": pos[:, 1],
            "z_um": pos[:, 2],
            "ux": u[:, 0],
            "uy": u[:, 1],
            "uz": u[:, 2],
            "theta_rad": theta,
            "psi_rad": psi,
            "phi_rad": phi,
            "alpha": 1.0,
        }
    )
    for name, value in static.items():
        df[name] = float(value)
    df["chi2"] = np.nan
    df["r2"] = np.nan
    df["status"] = OK
    df["message"] = ""
    return df


def simulate_trajectory(
    params: BrownianParameters,
    noise: MeasurementNoise | None = None,
    *,
    seed: int = 0,
    static: dict[str, float] | None = None,
    out_dir: str | Path | None = None,
) -> SimulatedTrajectory:
    """Simulate a trajectory and its measurement, as a fit table with the truth beside it.

    Parameters
    ----------
    params : BrownianParameters
        The dynamics.
    noise : MeasurementNoise, optional
        Noise and injected artefacts (none by default).
    seed : int
        Random seed (dynamics and measurement).
    static : dict, optional
        Static-parameter columns to write (e.g. ``{"a_um": 0.5, "b_um": 1.08}``).
    out_dir : str or Path, optional
        If given, write ``trajectory.csv`` (the measurement) and ``truth.csv`` (the noise-free
        trajectory), both in the fit-table schema with sidecars; ``trajectory.csv.json`` holds
        the truth parameters and the frames of every injected artefact.
    """
    noise = noise or MeasurementNoise()
    static = dict(static or {})
    rng = np.random.default_rng(seed)
    pos, rot = propagate_rigid_body(params, rng)
    n = params.n_frames
    dt = params.frame_interval_s
    frames = np.arange(n)
    pos_m, rot_m = _measured(pos, rot, noise, rng)
    picked = _artefacts(rot_m, noise, rng)

    table = _table(frames, dt, pos_m, rot_m, static)
    fail = picked["fail"]
    value_cols = [c for c in table.columns if c not in ("frame", "time_s", "status", "message")]
    table.loc[fail, value_cols] = np.nan
    table.loc[fail, "status"] = "failed"
    table.loc[fail, "message"] = "simulated failure"
    table = table.drop(index=picked["missing"]).reset_index(drop=True)
    truth = _table(frames, dt, pos, rot, static)

    truth_meta = {
        "dynamics": {**asdict(params), "substeps": params.steps_per_frame},
        "noise": asdict(noise),
        "seed": seed,
        "static": static,
        "flipped_frames": picked["flip"].tolist(),
        "mirrored_frames": picked["mirror"].tolist(),
        "failed_frames": picked["fail"].tolist(),
        "missing_frames": picked["missing"].tolist(),
        "d_t_um2_s": (params.d_par_um2_s + 2 * params.d_perp_um2_s) / 3,
    }
    result = SimulatedTrajectory(
        table, truth, truth_meta, picked["flip"], picked["mirror"], picked["fail"],
        picked["missing"],
    )
    if out_dir is not None:
        _write(result, Path(out_dir), dt, {"dynamics": asdict(params), "noise": asdict(noise),
                                           "seed": seed})
    return result


def _measured(pos: NDArray, rot: NDArray, noise: MeasurementNoise, rng: np.random.Generator
              ) -> tuple[NDArray, NDArray]:
    """The true positions (um) and rotations with the measurement noise of ``noise`` added."""
    n = len(pos)
    eps_z = noise.eps_xy_um if noise.eps_z_um is None else noise.eps_z_um
    sig = np.array([noise.eps_xy_um, noise.eps_xy_um, eps_z])
    pos_m = pos + rng.standard_normal((n, 3)) * sig
    rot_m = rot.copy()
    if noise.eps_r_rad > 0:
        w = rng.standard_normal((n, 3)) * (noise.eps_r_rad / math.sqrt(2.0))
        rot_m = rot_m @ rotation_from_vector(w)
    return pos_m, rot_m


def _artefacts(rot_m: NDArray, noise: MeasurementNoise, rng: np.random.Generator
               ) -> dict[str, NDArray]:
    """Choose the flipped, mirrored, failed and missing frames (disjoint); flips and mirrors
    are applied to ``rot_m`` in place."""
    n = len(rot_m)
    pool = np.arange(n)
    picked = {}
    for name in ("flip", "mirror", "fail", "missing"):
        chosen = _choose(rng, pool, getattr(noise, f"{name}_fraction"), n)
        picked[name] = chosen
        pool = np.setdiff1d(pool, chosen)
    flip_x = np.diag([1.0, -1.0, -1.0])  # Rx(pi): u -> -u
    mirror = np.diag([1.0, 1.0, -1.0])
    for k in picked["flip"]:
        rot_m[k] = rot_m[k] @ flip_x
    for k in picked["mirror"]:
        # M R M Rx(pi) is a proper rotation with axis (ux, uy, -uz)
        rot_m[k] = mirror @ rot_m[k] @ mirror @ flip_x
    return picked


def _write(result: SimulatedTrajectory, out: Path, dt: float, config: dict) -> None:
    """Write the truth and the measurement (fit-table schema, with sidecars) into ``out``."""
    truth, truth_meta = result.truth, result.truth_meta
    result.truth_path = write_table(
        out / "truth.csv",
        validate_fit_table(truth, str(out / "truth.csv"), dt).table,
        sidecar(
            kind="simulated trajectory, noise-free truth (fit-table schema)",
            units={c: column_unit(c) for c in truth.columns},
            extra={"frame_interval_s": dt, "truth": truth_meta},
        ),
    )
    result.fit = write_fit_table(
        out / "trajectory.csv",
        result.table,
        frame_interval_s=dt,
        kind="simulated trajectory (fit-table schema)",
        config=config,
        extra={"truth": truth_meta},
    )
    result.path = out / "trajectory.csv"
