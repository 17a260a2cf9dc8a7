"""Rotational-diffusion angle distribution and the projection correlation series (appendix)."""

import math

import numpy as np
import pytest
from scipy.integrate import quad
from scipy.special import lpmv

from holofit.analysis.projection import (
    projection_correlation,
    projection_correlation_derivative,
    s_l1,
)
from holofit.analysis.rotational_diffusion import angle_pdf, angle_tail, angle_threshold
from holofit.simulate.brownian import BrownianParameters, propagate_rigid_body


@pytest.mark.parametrize("x", [2e-4, 3e-3, 0.05, 0.5, 3.0])
def test_angle_pdf_normalised_and_tail_consistent(x):
    th = np.linspace(0, np.pi, 40001)
    p = angle_pdf(th, x)
    assert np.trapezoid(p, th) == pytest.approx(1.0, abs=1e-5)
    cum = np.concatenate([[0], np.cumsum(0.5 * (p[1:] + p[:-1]) * np.diff(th))])
    probe = [100, 3000, 20000, 39000]
    np.testing.assert_allclose(angle_tail(th[probe], x), 1 - cum[probe], atol=2e-5)
    assert angle_tail(np.array([0.0]), x)[0] == pytest.approx(1.0, abs=1e-12)
    assert angle_tail(np.array([np.pi]), x)[0] == pytest.approx(0.0, abs=1e-12)


def test_small_time_limit_is_planar_rayleigh():
    x = 1e-5
    th = np.array([0.002, 0.006, 0.01, 0.015])
    np.testing.assert_allclose(angle_tail(th, x), np.exp(-(th**2) / (4 * x)), rtol=2e-4)
    # just above the switch-over the series agrees with the planar formula used below it
    x = 1.5e-7
    assert angle_threshold(x, 1e-4) == pytest.approx(math.sqrt(-4 * x * math.log(1e-4)),
                                                     rel=1e-5)


@pytest.mark.parametrize(("x", "p"), [(0.003, 1e-4), (0.03, 1e-4), (0.3, 1e-2), (1e-6, 1e-4)])
def test_threshold_inverts_the_tail(x, p):
    th = angle_threshold(x, p)
    assert angle_tail(np.array([th]), x)[0] == pytest.approx(p, rel=1e-6)


def test_threshold_at_long_lags_is_that_of_a_uniform_direction():
    # uniform on the sphere: P(angle >= th) = (1 + cos th) / 2
    assert angle_threshold(20.0, 1e-4) == pytest.approx(math.acos(2e-4 - 1), rel=1e-9)


def _simulated_axis(d_r, dt, n, seed=0):
    p = BrownianParameters(n, dt, 0.0, 0.0, d_r)
    _, rot = propagate_rigid_body(p, np.random.default_rng(seed))
    return rot[:, :, 2]


def test_tail_matches_beard_schlick_simulation():
    d_r, dt = 0.5, 0.02
    u = _simulated_axis(d_r, dt, 200_000)
    for lag in (1, 10):
        a, b = u[:-lag:lag], u[lag::lag]  # non-overlapping pairs are independent
        ang = np.arccos(np.clip(np.sum(a * b, axis=1), -1, 1))
        x = d_r * lag * dt
        for q in (0.5, 0.1, 0.01):
            th = angle_threshold(x, q)
            frac = np.mean(ang >= th)
            assert abs(frac - q) < 4 * math.sqrt(q * (1 - q) / ang.size) + 1e-4


def test_s_l1_recursion_matches_quadrature():
    s = s_l1(8)
    for i in range(8):
        l = 2 * i + 1
        assert s[i] == pytest.approx(quad(lambda x, l=l: lpmv(1, l, x), -1, 1, limit=200)[0],
                                     rel=1e-8)


def test_projection_series_is_one_at_zero_and_single_exponential_for_l1():
    assert projection_correlation(0.7, np.array([0.0]))[0] == pytest.approx(1.0, abs=1e-8)
    tau = np.array([0.0, 0.1, 1.0, 3.0])
    np.testing.assert_allclose(projection_correlation(0.7, tau, n_odd=1),
                               3 * math.pi**2 / 32 * np.exp(-2 * 0.7 * tau), rtol=1e-14)
    # at long lags only l = 1 survives
    assert projection_correlation(0.7, np.array([5.0]))[0] == pytest.approx(
        projection_correlation(0.7, np.array([5.0]), n_odd=1)[0], rel=1e-9)


def test_projection_derivative():
    tau = np.array([0.01, 0.1, 1.0])
    h = 1e-6
    num = (projection_correlation(0.5 + h, tau) - projection_correlation(0.5 - h, tau)) / (2 * h)
    np.testing.assert_allclose(projection_correlation_derivative(0.5, tau), num, rtol=1e-6)


def test_projection_series_matches_simulation():
    d_r, dt = 0.5, 0.05
    u = _simulated_axis(d_r, dt, 400_000, seed=3)
    psi = np.arctan2(u[:, 1], u[:, 0])
    for lag in (1, 4, 20):
        c = np.cos(psi[lag:] - psi[:-lag])
        # neighbouring pairs are correlated: use the scatter of 40 block means
        blocks = c[: c.size // 40 * 40].reshape(40, -1).mean(axis=1)
        err = blocks.std(ddof=1) / math.sqrt(40)
        expect = projection_correlation(d_r, np.array([lag * dt]))[0]
        assert abs(c.mean() - expect) < 4 * err
