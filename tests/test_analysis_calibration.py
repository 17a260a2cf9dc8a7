"""Full validation studies (slow): error calibration over 20 rods, long projection runs.

Run with ``pytest -m slow -s tests/test_analysis_calibration.py`` to see the numbers.
"""

import math

import numpy as np
import pytest

from holofit.analysis.validation import (
    L1_AMPLITUDE,
    projection_study,
    rod_study,
    single_exponential_bias,
)

pytestmark = pytest.mark.slow


def test_rod_errors_calibrated_over_20_seeds():
    # the study: 2000 frames at 100 frames/s, seeds 0-19
    rows = rod_study(n_seeds=20, n_frames=2000, first_seed=0)
    print()
    for row in rows.values():
        print(row.line())
    for key in ("D_par", "D_perp", "D_t", "D_r", "D_par/D_perp", "eps_par", "eps_perp"):
        row = rows[key]
        assert abs(row.bias_in_se) < 2, row.line()
        assert 1 / 1.5 < row.error_ratio < 1.5, row.line()


@pytest.mark.parametrize(
    ("d_r", "dt", "n_frames", "n_runs"),
    # D_r * dt = 0.05 and 0.02: 2e5 rotational times in all for each case
    [(0.5, 0.1, 1_000_000, 4), (0.05, 0.4, 1_000_000, 10)],
)
def test_projection_fit_recovers_d_r_on_long_runs(d_r, dt, n_frames, n_runs):
    runs = projection_study(d_r, dt, n_frames, n_runs)
    values = np.array([r.d_r for r in runs])
    errors = np.array([r.error for r in runs])
    mean = values.mean()
    se = math.sqrt(np.sum(errors**2)) / len(errors)
    single = np.mean([r.single_exponential for r in runs])
    print(f"\nD_r = {d_r}: {n_runs} x {n_frames} frames at {dt} s, fit lags {runs[0].lags}: "
          f"{mean:.5g} ({100 * (mean / d_r - 1):+.3f} % +- {100 * se / d_r:.3f} %), "
          f"per run {np.round(100 * (values / d_r - 1), 2)} %, "
          f"single exponential {100 * (single / d_r - 1):+.1f} %")
    assert abs(mean / d_r - 1) < 0.005
    assert abs(mean - d_r) < 3 * se
    assert single > 1.05 * d_r


def test_single_exponential_bias_table():
    print("\nD_r tau_max   l=1 term alone   A exp(-2 D tau), A free   exp(-2 D tau)")
    for x in (0.01, 0.03, 0.1, 0.3, 1.0, 3.0):
        l1 = single_exponential_bias(x, amplitude=L1_AMPLITUDE)
        free = single_exponential_bias(x, amplitude=True)
        one = single_exponential_bias(x, amplitude=1.0)
        print(f"{x:10.2f}   {100 * l1:+13.1f} %   {100 * free:+22.1f} %   {100 * one:+12.1f} %")
        assert free > 0 and one > 0
    # short lags: biased by tens of percent (the l = 1 term alone even turns D_r negative,
    # since it starts at 3 pi^2 / 32 = 0.925 < 1); it is right only at long lags
    assert single_exponential_bias(0.1, amplitude=True) > 0.2
    assert abs(single_exponential_bias(0.1, amplitude=L1_AMPLITUDE)) > 0.2
    assert abs(single_exponential_bias(3.0, amplitude=L1_AMPLITUDE)) < 0.01
