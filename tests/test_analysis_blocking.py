"""Flyvbjerg-Petersen block decorrelation against series with known error of the mean."""

import numpy as np
import pytest

from holofit.analysis.blocking import block_levels, block_standard_error, block_standard_errors


def _ar1(rng, n, rho, m=1):
    x = np.empty((m, n))
    x[:, 0] = rng.normal(size=m)
    e = rng.normal(size=(m, n)) * np.sqrt(1 - rho**2)
    for i in range(1, n):
        x[:, i] = rho * x[:, i - 1] + e[:, i]
    return x


def test_independent_values_give_the_naive_error():
    rng = np.random.default_rng(0)
    x = rng.normal(3.0, 2.0, 4096)
    res = block_standard_error(x)
    assert res.converged and res.n == 4096
    assert res.mean == pytest.approx(x.mean())
    assert res.sem == pytest.approx(x.std() / np.sqrt(x.size - 1), rel=0.25)


def test_correlated_series_error_matches_exact_and_scatter():
    # AR(1): exact SE of the mean ~ sqrt((1 + rho) / (1 - rho) / n) for unit variance
    rng = np.random.default_rng(1)
    rho, n = 0.9, 8192
    x = _ar1(rng, n, rho, m=200)
    mean, sem, _, conv = block_standard_errors(x)
    exact = np.sqrt((1 + rho) / (1 - rho) / n)
    assert conv.mean() > 0.9
    assert np.sqrt(np.mean(sem**2)) == pytest.approx(exact, rel=0.1)
    assert np.std(mean) == pytest.approx(exact, rel=0.15)  # scatter of 200 independent means
    naive = block_levels(x[0])[1][0]
    assert naive < 0.4 * exact  # what ignoring the correlation would report


def test_constant_and_short_series():
    assert block_standard_error(np.full(100, 2.5)).sem == 0.0
    assert np.isnan(block_standard_error([1.0]).sem)
    sizes, _, counts = block_levels(np.arange(10.0))
    assert list(sizes) == [1, 2, 4] and list(counts) == [10, 5, 2]
