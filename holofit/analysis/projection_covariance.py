"""Covariance of the projected-orientation correlation at several lags, by simulation.

``<p(t) . p(t + k)>`` (``p`` the unit projection of the axis on the x-y plane, paper
appendix) is averaged over overlapping pairs, so its values at neighbouring lags are strongly
correlated, and the four-point functions of isotropic rotational diffusion that would give
their covariance in closed form are unwieldy. Instead we simulate: ``n_sim`` independent
axes diffusing with the fitted ``D_r`` (exact finite rotations of a Gaussian rotation
vector, ``D_r h <= 1e-2`` per substep: the effective coefficient ``D_r (1 + D_r h / 6)`` is
0.2 % high at most, which changes a covariance negligibly), sampled on the trajectory's
frame grid with its gaps, give the lag averages' sample covariance. Fixed seeds make it
reproducible. A run longer than :data:`MAX_SIM_FRAMES` is simulated that long (without
gaps) and the covariance scaled by the ratio of usable frames (a time average's variance
falls as one over its length once the run is much longer than the
correlation time ``1 / (2 D_r)``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numba
import numpy as np
from numpy.typing import NDArray

__all__ = ["MAX_SIM_FRAMES", "N_SIM", "projection_covariance", "simulate_axes"]

#: simulated axes per covariance (the error of an error from it: about 1 / sqrt(2 N_SIM), 6 %)
N_SIM = 128
#: longest simulated run, frames
MAX_SIM_FRAMES = 8192
#: largest D_r h of one substep
_MAX_STEP = 1e-2


@numba.njit(cache=True)
def _axes(u0: np.ndarray, n: int, sigma: float, substeps: int, seed: int) -> np.ndarray:
    # numba's own generator (a Generator cannot be drawn from inside this loop), seeded
    np.random.seed(seed)  # noqa: NPY002
    k = u0.shape[0]
    out = np.empty((k, n, 3))
    u = np.empty(3)
    for i in range(k):
        u[:] = u0[i]
        out[i, 0] = u
        for f in range(1, n):
            for _ in range(substeps):
                wx = sigma * np.random.standard_normal()  # noqa: NPY002
                wy = sigma * np.random.standard_normal()  # noqa: NPY002
                wz = sigma * np.random.standard_normal()  # noqa: NPY002
                ang = math.sqrt(wx * wx + wy * wy + wz * wz)
                if ang > 0.0:
                    kx, ky, kz = wx / ang, wy / ang, wz / ang
                    c, sn = math.cos(ang), math.sin(ang)
                    kd = kx * u[0] + ky * u[1] + kz * u[2]
                    cx = ky * u[2] - kz * u[1]
                    cy = kz * u[0] - kx * u[2]
                    cz = kx * u[1] - ky * u[0]
                    u[0] = u[0] * c + cx * sn + kx * kd * (1.0 - c)
                    u[1] = u[1] * c + cy * sn + ky * kd * (1.0 - c)
                    u[2] = u[2] * c + cz * sn + kz * kd * (1.0 - c)
            nrm = math.sqrt(u[0] * u[0] + u[1] * u[1] + u[2] * u[2])
            u[0] /= nrm
            u[1] /= nrm
            u[2] /= nrm
            out[i, f] = u
    return out


def simulate_axes(
    d_r: float, frame_interval_s: float, n_frames: int, n_sim: int, seed: int = 0
) -> NDArray[np.float64]:
    """``n_sim`` unit axes diffusing isotropically from uniform random starts.

    Returns
    -------
    ndarray, shape (n_sim, n_frames, 3)
    """
    rng = np.random.default_rng(seed)
    u0 = rng.standard_normal((n_sim, 3))
    u0 /= np.linalg.norm(u0, axis=1, keepdims=True)
    x = max(d_r, 0.0) * frame_interval_s
    substeps = max(1, min(math.ceil(x / _MAX_STEP), 256))
    return _axes(u0, n_frames, math.sqrt(2.0 * x / substeps), substeps, seed)


def projection_covariance(
    d_r: float,
    frame_interval_s: float,
    lags: Sequence[int] | NDArray[np.int64],
    masks: Sequence[NDArray[np.bool_]],
    n_sim: int = N_SIM,
    seed: int = 0,
) -> NDArray[np.float64]:
    """Covariance matrix of the time-averaged ``<p . p'>`` at ``lags`` for a run whose usable
    pairs at lag ``k`` are ``masks[i]`` (length ``N - k``).

    Parameters
    ----------
    d_r : float
        Rotational diffusion coefficient, 1/s.
    frame_interval_s : float
        Time between frames, s.
    """
    lags = np.asarray(lags, dtype=np.int64)
    n = int(lags[0] + masks[0].size)
    counts = np.array([float(np.count_nonzero(m)) for m in masks])
    n_run = min(n, max(MAX_SIM_FRAMES, int(lags.max()) * 8))
    scaled = n_run < n
    u = simulate_axes(d_r, frame_interval_s, n_run, n_sim, seed)
    p = u[:, :, :2] / np.maximum(np.hypot(u[:, :, 0], u[:, :, 1]), 1e-300)[:, :, None]
    px, py = p[:, :, 0], p[:, :, 1]
    means = np.empty((n_sim, lags.size))
    sim_counts = np.empty(lags.size)
    if scaled or all(m.all() for m in masks):  # no gaps: every lag at once, by FFT
        nfft = 1 << int(np.ceil(np.log2(2 * n_run)))
        corr = np.zeros((n_sim, nfft))
        for c in (px, py):
            corr += np.fft.irfft(np.abs(np.fft.rfft(c, nfft, axis=1)) ** 2, nfft, axis=1)
        sim_counts = (n_run - lags).astype(float)
        means = corr[:, lags] / sim_counts
        lags_done = True
    else:
        lags_done = False
    for i, k in enumerate([] if lags_done else lags):
        k = int(k)
        dots = px[:, k:] * px[:, :-k] + py[:, k:] * py[:, :-k]
        if scaled:
            means[:, i] = dots.mean(axis=1)
            sim_counts[i] = dots.shape[1]
        else:
            means[:, i] = dots[:, masks[i]].mean(axis=1)
            sim_counts[i] = counts[i]
    cov = np.cov(means, rowvar=False).reshape(lags.size, lags.size)
    if scaled:
        f = np.sqrt(sim_counts / np.maximum(counts, 1.0))
        cov = cov * np.outer(f, f)
    return cov
