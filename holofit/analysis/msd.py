"""Time-averaged displacement statistics at many lags, with block-decorrelated errors.

For every lag ``k`` (frames) an *observable* turns each usable pair of frames ``(t, t + k)``
into one number ``x_t(k)`` (a squared displacement, a dot product); its time average is the
mean-square displacement or correlation at that lag, and the Flyvbjerg-Petersen error of that
average (:mod:`holofit.analysis.blocking`) is its error bar. A pair is usable when both frames
are valid and the pair filter (the rejection of improbable angular jumps) accepts it.

Observables, with ``dr = r(t + k) - r(t)`` and ``u = u(t)`` (the particle frame at the start):

* ``par``: ``(dr . u)^2``, expectation ``2 D_par tau + 2 eps_par^2``;
* ``perp``: ``|dr x u|^2``, expectation ``4 D_perp tau + 4 eps_perp^2``;
* ``lab_x``, ``lab_y``, ``lab_z``: ``dx^2``, ``dy^2``, ``dz^2`` (``2 D tau + 2 eps^2`` each);
* ``lab_3d``: ``|dr|^2`` (``6 D_t tau + 6 eps^2`` for isotropic noise);
* ``xy``: ``dx^2 + dy^2``, expectation ``4 D tau + 4 eps^2``;
* ``orient``: ``|u(t + k) - u(t)|^2``, expectation ``2 (1 - exp(-2 D_r tau)) + 2 eps_r^2``;
* ``proj``: ``p(t) . p(t + k)`` with ``p = (cos psi, sin psi)``: the appendix series.

The particle-frame expressions hold while the axis turns little within a lag
(``6 D_r tau << 1``); beyond that both MSDs tend to the orientation average.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from holofit.analysis.blocking import block_standard_errors

__all__ = [
    "OBSERVABLES",
    "LagStatistics",
    "Observables",
    "default_lags",
    "influence_series",
    "lag_statistics",
    "pair_mask",
]

PairFilter = Callable[[int], NDArray[np.bool_] | None]

OBSERVABLES = ("par", "perp", "lab_x", "lab_y", "lab_z", "lab_3d", "xy", "orient", "proj")
_POSITIONAL = ("par", "perp", "lab_x", "lab_y", "lab_z", "lab_3d", "xy")


@dataclass
class Observables:
    """Per-pair quantities of a trajectory (positions drift-corrected, axes cleaned).

    Parameters
    ----------
    position_um : ndarray, shape (N, 3)
    axis : ndarray, shape (N, 3) or None
    valid : ndarray of bool, shape (N,)
    """

    position_um: NDArray[np.float64]
    axis: NDArray[np.float64] | None
    valid: NDArray[np.bool_]

    def __post_init__(self) -> None:
        self._proj: NDArray[np.float64] | None = None
        if self.axis is not None:
            psi = np.arctan2(self.axis[:, 1], self.axis[:, 0])
            self._proj = np.stack([np.cos(psi), np.sin(psi)], axis=1)

    def values(
        self, names: Sequence[str], lag: int, mask: NDArray[np.bool_]
    ) -> NDArray[np.float64]:
        """``x_t(lag)`` for the origins where ``mask`` (length ``N - lag``) is set, one row per
        name."""
        out = np.empty((len(names), int(np.count_nonzero(mask))))
        dr = (self.position_um[lag:] - self.position_um[:-lag])[mask]
        needs_axis = any(n in ("par", "perp", "orient", "proj") for n in names)
        if needs_axis and (self.axis is None or self._proj is None):
            raise ValueError(f"observables {', '.join(names)} need an axis; this trajectory "
                             "has none")
        axis = self.axis if self.axis is not None else np.zeros_like(self.position_um)
        pp = self._proj if self._proj is not None else np.zeros((axis.shape[0], 2))
        u0 = axis[:-lag][mask]
        for i, name in enumerate(names):
            if name == "par":
                out[i] = np.einsum("ij,ij->i", dr, u0) ** 2
            elif name == "perp":
                proj = np.einsum("ij,ij->i", dr, u0)
                out[i] = np.einsum("ij,ij->i", dr, dr) - proj**2
            elif name == "lab_x":
                out[i] = dr[:, 0] ** 2
            elif name == "lab_y":
                out[i] = dr[:, 1] ** 2
            elif name == "lab_z":
                out[i] = dr[:, 2] ** 2
            elif name == "lab_3d":
                out[i] = np.einsum("ij,ij->i", dr, dr)
            elif name == "xy":
                out[i] = dr[:, 0] ** 2 + dr[:, 1] ** 2
            elif name == "orient":
                du = (axis[lag:] - axis[:-lag])[mask]
                out[i] = np.einsum("ij,ij->i", du, du)
            elif name == "proj":
                out[i] = (pp[:-lag, 0] * pp[lag:, 0] + pp[:-lag, 1] * pp[lag:, 1])[mask]
            else:
                raise ValueError(f"unknown observable {name!r}; known: {', '.join(OBSERVABLES)}")
        return out


def pair_mask(valid: NDArray[np.bool_], lag: int, pair_filter: PairFilter | None) -> NDArray:
    """Mask over origins ``t < N - lag`` of the usable pairs ``(t, t + lag)``."""
    ok = valid[:-lag] & valid[lag:]
    if pair_filter is not None:
        extra = pair_filter(lag)
        if extra is not None:
            ok &= extra
    return ok


@dataclass
class LagStatistics:
    """Time averages of one observable at several lags."""

    name: str
    lags: NDArray[np.int64]
    tau_s: NDArray[np.float64]
    mean: NDArray[np.float64]
    sem: NDArray[np.float64]
    count: NDArray[np.int64]
    rejected: NDArray[np.int64]
    converged: NDArray[np.bool_]

    def at(self, lags: NDArray[np.int64]) -> LagStatistics:
        """The subset at the given lags (which must all be present)."""
        idx = np.searchsorted(self.lags, lags)
        if np.any(idx >= self.lags.size) or np.any(self.lags[np.minimum(idx, self.lags.size - 1)]
                                                   != lags):
            raise ValueError("requested lags were not computed")
        return LagStatistics(
            self.name, self.lags[idx], self.tau_s[idx], self.mean[idx], self.sem[idx],
            self.count[idx], self.rejected[idx], self.converged[idx],
        )


def default_lags(n_frames: int, max_lag: int | None = None, dense: int = 20,
                 n_log: int = 50) -> NDArray[np.int64]:
    """Every lag up to ``dense``, then about ``n_log`` log-spaced lags up to ``max_lag``.

    ``max_lag`` defaults to a quarter of the trajectory.
    """
    top = max(1, min(max_lag if max_lag is not None else n_frames // 4, n_frames - 1))
    dense_lags = np.arange(1, min(dense, top) + 1)
    log_lags = np.unique(np.round(np.geomspace(1, top, n_log)).astype(np.int64))
    return np.union1d(dense_lags, log_lags)


def lag_statistics(
    obs: Observables,
    names: Sequence[str],
    lags: NDArray[np.int64],
    frame_interval_s: float,
    pair_filter: PairFilter | None = None,
) -> dict[str, LagStatistics]:
    """Means and block-decorrelated errors of each observable at each lag.

    Lags with fewer than two usable pairs get NaN.
    """
    lags = np.unique(np.asarray(lags, dtype=np.int64))
    lags = lags[(lags >= 1) & (lags < obs.valid.size)]
    m = len(names)
    mean = np.full((m, lags.size), np.nan)
    sem = np.full((m, lags.size), np.nan)
    count = np.zeros(lags.size, np.int64)
    rejected = np.zeros(lags.size, np.int64)
    conv = np.zeros((m, lags.size), bool)
    for i, lag in enumerate(lags):
        both = int(np.count_nonzero(obs.valid[:-lag] & obs.valid[lag:]))
        mask = pair_mask(obs.valid, int(lag), pair_filter)
        count[i] = int(np.count_nonzero(mask))
        rejected[i] = both - count[i]
        if count[i] < 2:
            continue
        x = obs.values(names, int(lag), mask)
        mean[:, i], sem[:, i], _, conv[:, i] = block_standard_errors(x)
    tau = np.asarray(lags * frame_interval_s, dtype=np.float64)
    return {
        name: LagStatistics(name, lags, tau, mean[k], sem[k], count, rejected, conv[k])
        for k, name in enumerate(names)
    }


def influence_series(
    obs: Observables,
    name: str,
    stats: LagStatistics,
    weights: NDArray[np.float64],
    pair_filter: PairFilter | None = None,
) -> NDArray[np.float64]:
    """Per-origin contributions of a linear combination of the lag averages.

    For ``q = sum_k weights[:, k] * mean(lag_k)`` returns ``y`` of shape (P, N) with
    ``q - q_hat = sum_t y[:, t]`` to first order: each origin ``t`` adds
    ``weights[:, k] (x_t(lag_k) - mean_k) / count_k`` for every lag at which it is used.
    """
    w = np.atleast_2d(weights)
    n = obs.valid.size
    y = np.zeros((w.shape[0], n))
    c = np.empty(n)
    for k, lag in enumerate(stats.lags):
        if stats.count[k] < 2:
            continue
        lag = int(lag)
        mask = pair_mask(obs.valid, lag, pair_filter)
        x = obs.values([name], lag, mask)[0]
        c[: n - lag] = 0.0
        c[: n - lag][mask] = (x - stats.mean[k]) / stats.count[k]
        for p in range(w.shape[0]):
            y[p, : n - lag] += w[p, k] * c[: n - lag]
    return y
