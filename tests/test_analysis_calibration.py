"""Full validation studies (slow): error calibration at every length, long projection runs.

Run with ``pytest -m slow -s tests/test_analysis_calibration.py`` to see the numbers; the full
study (200 trajectories per case) is ``bench/calibration.py``.
"""

import math

import numpy as np
import pytest

from holofit.studies.diffusion import (
    L1_AMPLITUDE,
    calibration_case,
    projection_study,
    pull_bounds,
    rod_study,
    single_exponential_bias,
)

pytestmark = pytest.mark.slow

#: trajectories per case: the bounds widen with 3 standard errors of this count
#: (pull_bounds(100): |mean| <= 0.45, s.d. in [0.71, 1.33])
N_SEEDS = 100


@pytest.mark.parametrize("noise", ["replicate", "paper"])
@pytest.mark.parametrize("model", ["rod", "janus", "sphere"])
@pytest.mark.parametrize("n_frames", [30, 300, 2000])
def test_errors_calibrated_at_every_length(model, noise, n_frames):
    # the target: pull mean within 0.15 of 0 and s.d. within [0.9, 1.1], here on fewer
    # trajectories than bench/calibration.py with the bounds their number allows
    mean_bound, (sd_lo, sd_hi) = pull_bounds(N_SEEDS)
    print()
    for row in calibration_case(model, noise, n_frames, N_SEEDS, first_seed=50).values():
        r = row.row()
        print(f"{model} {noise} {n_frames} {r['quantity']}: pull mean {r['pull_mean']:+.2f} "
              f"s.d. {r['pull_sd']:.2f} (bias {100 * r['bias_rel']:+.1f} %)")
        assert row.failed == 0
        if model == "janus" and r["quantity"] == "D_r" and n_frames == 30:
            # D_r T = 0.35: not resolved (errors ~110 %, scatter ~200 %, right-skewed); what
            # can be asked is that it says so, and that its interval covers (conservatively)
            assert r["rel_error"] > 0.5 and row.sd <= sd_hi, r
            assert r["within_1_sigma"] >= 0.683 - 3 * math.sqrt(0.683 * 0.317 / N_SEEDS), r
            continue
        assert abs(row.mean) <= mean_bound, r
        assert sd_lo <= row.sd <= sd_hi, r


def test_janus_rotation_interval_covers_on_each_side():
    # the projection fit's interval: the truth above its upper end in 15.9 % of runs (and
    # below its lower end as often). With the sandwich sensitivity held at the estimate the
    # upper errors of low estimates were too small: the truth lay above the upper end in
    # 23.5 % of 200 runs at 300 frames, mean pull -0.33
    n = 400
    row = calibration_case("janus", "replicate", 300, n, first_seed=20_000)["D_r"]
    mean_bound, _ = pull_bounds(n)
    se = math.sqrt(0.159 * 0.841 / n)
    above, below = float(np.mean(row.pulls < -1)), float(np.mean(row.pulls > 1))
    print(f"\njanus D_r 300 frames: pull mean {row.mean:+.2f} s.d. {row.sd:.2f}, truth above "
          f"the interval {100 * above:.1f} %, below {100 * below:.1f} %")
    assert row.failed == 0
    assert abs(row.mean) <= mean_bound
    assert abs(above - 0.159) <= 3 * se and abs(below - 0.159) <= 3 * se


def test_rod_with_artefacts_calibrated_over_20_seeds():
    # the paper's rod with flips and mirrored outliers (the cleaning in the loop): 2000 frames
    rows = rod_study(n_seeds=20, n_frames=2000, first_seed=0)
    _, (sd_lo, sd_hi) = pull_bounds(20)
    print()
    for row in rows.values():
        print(row.line())
    for key in ("D_par", "D_perp", "D_t", "D_r", "D_par/D_perp"):
        row = rows[key]
        assert abs(row.bias_in_se) < 3, row.line()
        # rms error / scatter: a ratio of two estimates; its spread is that of the scatter
        assert sd_lo <= 1 / row.error_ratio <= sd_hi, row.line()


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
