"""What an analysis found: :class:`AnalysisResult` (and its JSON form)."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from holofit.analysis.cleaning import OrientationCleaning
from holofit.analysis.consistency import Consistency
from holofit.analysis.hydrodynamics import Prediction
from holofit.analysis.linefit import FitResult
from holofit.analysis.measurement import Measurement
from holofit.analysis.msd import LagStatistics
from holofit.analysis.settings import AnalysisConfig
from holofit.analysis.trajectory import Trajectory

__all__ = ["AnalysisResult", "Measurement"]

#: lags at which the cleaning's thresholds and rejected pairs are reported
REPORTED_LAGS = (1, 2, 5, 10, 20, 50, 100)


@dataclass
class AnalysisResult:
    """Everything :func:`holofit.analysis.pipeline.analyze_trajectory` found.

    Attributes
    ----------
    settings : AnalysisConfig
        How it was analysed.
    trajectory : Trajectory
        What was analysed.
    valid : ndarray of bool
        Frames used (after cleaning).
    drift_um_s : ndarray, shape (3,)
        The drift velocity removed, um/s.
    cleaning : OrientationCleaning or None
        Flips and rejections (None without orientation).
    stats : dict
        Observable -> lag statistics.
    fits : dict
        Fit key -> fit of a lag statistic.
    measured : dict
        Quantity -> :class:`Measurement`.
    predictions : dict
        Key -> (prediction, unit, source).
    sizes : dict
        ``a_um``/``b_um`` -> (value, error, source).
    rows : list of dict
        The summary table (:func:`holofit.analysis.summary.summary_rows`).
    notes : list of str
        What the user should know.
    drift_err_um_s : ndarray, shape (3,)
        The Brownian 1-sigma error of the end-to-end drift velocity, um/s (NaN if unknown).
    consistency : Consistency, optional
        The physical-consistency tests and whether the track is flagged
        (:mod:`holofit.analysis.consistency`; None when not checked).
    """

    settings: AnalysisConfig
    trajectory: Trajectory
    valid: NDArray[np.bool_]
    drift_um_s: NDArray[np.float64]
    cleaning: OrientationCleaning | None
    stats: dict[str, LagStatistics]
    fits: dict[str, FitResult]
    measured: dict[str, Measurement]
    predictions: dict[str, tuple[Prediction, str, str]]
    sizes: dict[str, tuple[float, float, str]]
    rows: list[dict[str, Any]]
    notes: list[str] = field(default_factory=list)
    drift_err_um_s: NDArray[np.float64] = field(default_factory=lambda: np.full(3, np.nan))
    consistency: Consistency | None = None

    @property
    def flagged(self) -> bool:
        """The consistency check failed (the track is left out of pooled results)."""
        return self.consistency is not None and self.consistency.flagged

    def summary(self) -> dict[str, Any]:
        """A JSON-ready description of the analysis."""
        traj = self.trajectory
        cl = self.cleaning
        doc: dict[str, Any] = {
            "settings": asdict(self.settings),
            "input": traj.source,
            "frame_interval_s": traj.frame_interval_s,
            "frames": {
                "first": traj.first_frame,
                "slots": traj.n_frames,
                "with_fit": int(traj.valid.sum()),
                "gaps": int((~traj.valid).sum()),
                "used": int(self.valid.sum()),
            },
            "drift_um_s": self.drift_um_s.tolist(),
            "drift_err_um_s": self.drift_err_um_s.tolist(),
            "measured": {k: asdict(v) for k, v in self.measured.items()},
            "predictions": {
                k: {**asdict(p), "unit": unit, "source": src}
                for k, (p, unit, src) in self.predictions.items()
            },
            "sizes_um": {k: {"value": v, "error": e, "source": s}
                         for k, (v, e, s) in self.sizes.items()},
            "fits": {k: _fit_summary(f) for k, f in self.fits.items()},
            "table": self.rows,
            "notes": self.notes,
        }
        if self.consistency is not None:
            doc["consistency"] = self.consistency.summary()
        if cl is not None:
            first = next(iter(self.stats.values()))
            doc["cleaning"] = {
                "head_tail_flips": int(cl.flipped.sum()),
                "flipped_frames": (traj.frames[cl.flipped]).tolist(),
                "rejected_frames": (traj.frames[cl.outliers]).tolist(),
                "d_est_s": cl.estimate.d_est if cl.estimate else None,
                "d_est_source": cl.estimate.source if cl.estimate else None,
                "eps_r_est_rad": cl.estimate.eps_r if cl.estimate else None,
                "probability": self.settings.reject_probability,
                "threshold_rad_by_lag": (
                    {int(k): cl.thresholds(int(k)) for k in REPORTED_LAGS if k < traj.n_frames}
                    if cl.thresholds is not None else {}
                ),
                "rejected_pairs_by_lag": {
                    int(k): int(r) for k, r in zip(first.lags, first.rejected, strict=True)
                    if k in REPORTED_LAGS
                },
            }
        return doc


def _fit_summary(f: FitResult) -> dict[str, Any]:
    return {
        "observable": f.observable,
        "model": f.model.formula,
        "parameters": dict(zip(f.model.params, f.values.tolist(), strict=True)),
        "errors": dict(zip(f.model.params, f.errors.tolist(), strict=True)),
        "error_method": f.method,
        "errors_if_lags_independent": dict(
            zip(f.model.params, f.naive_errors.tolist(), strict=True)
        ),
        "lags_frames": [int(f.lags[0]), int(f.lags[-1])],
        "tau_s": [float(f.tau_s[0]), float(f.tau_s[-1])],
        "chi2_reduced": f.chi2_reduced,
        "error_plateau_found": f.error_converged,
        "converged": f.success,
    }
