"""The linear system: FFT convolution, QMR, warm starts, loud failures."""

import numpy as np
import pytest

from holofit.dda.convolution import Convolver
from holofit.dda.dipoles import DipoleSystem
from holofit.dda.engine import BuiltinDDA
from holofit.dda.interaction import get_interaction, green_tensor
from holofit.dda.solver import ConvergenceError, qmr_cs
from holofit.dda.voxelize import voxelize
from holofit.optics import Optics
from holofit.particles import Spherocylinder
from holofit.scattering.theory import Orientation

OPTICS = Optics(0.66, 1.33, 0.0)


@pytest.mark.parametrize("backend", ["fftw", "numpy"])
@pytest.mark.parametrize("dtype,tol", [(np.complex128, 1e-12), (np.complex64, 1e-5)])
@pytest.mark.parametrize("box", [(3, 4, 5), (6, 2, 3), (7, 5, 2)])
def test_fft_convolution_equals_direct_sum(box, dtype, tol, backend, monkeypatch):
    from holofit.dda import fftw

    if backend == "numpy":
        monkeypatch.setenv("HOLOFIT_FFT", "numpy")
    elif not fftw.available(dtype):
        pytest.skip("FFTW not installed")
    d, k = 0.05, 12.0
    rng = np.random.default_rng(0)
    idx = np.stack(np.meshgrid(*(np.arange(n) for n in box), indexing="ij"), -1).reshape(-1, 3)
    ijk = idx[rng.random(len(idx)) < 0.7]  # a box with holes
    conv = Convolver(get_interaction(box, d, k, dtype), box, ijk)
    assert conv.backend == backend
    v = rng.normal(size=3 * len(ijk)) + 1j * rng.normal(size=3 * len(ijk))
    w = rng.normal(size=len(ijk)) + 1j * rng.normal(size=len(ijk))
    g = green_tensor((ijk[:, None, :] - ijk[None, :, :]) * d, k)  # (N, N, 3, 3), G(0) = 0
    conv_ref = np.einsum("ijab,jb->ia", g, v.reshape(-1, 3)).ravel()
    got = conv.convolve(v)
    assert np.max(np.abs(got - conv_ref)) < tol * np.max(np.abs(conv_ref))
    # the DDA operator v - w G (w v), twice (buffers are reused between products)
    wv = (w[:, None] * v.reshape(-1, 3)).ravel()
    op_ref = v - (w[:, None] * np.einsum("ijab,jb->ia", g, wv.reshape(-1, 3))).ravel()
    for _ in range(2):
        got = conv.product(v, w)
        assert np.max(np.abs(got - op_ref)) < tol * np.max(np.abs(op_ref))


def test_qmr_on_random_complex_symmetric_system():
    rng = np.random.default_rng(1)
    n = 200
    a = rng.normal(size=(n, n)) + 1j * rng.normal(size=(n, n))
    a = 0.04 * (a + a.T) + (1.0 + 0.5j) * np.eye(n)
    b = rng.normal(size=n) + 1j * rng.normal(size=n)
    res = qmr_cs(lambda v: a @ v, b, tol=1e-10)
    assert res.converged
    assert np.linalg.norm(a @ res.x - b) / np.linalg.norm(b) < 2e-10  # the true residual


def test_nonconvergence_is_loud():
    lat = voxelize(Spherocylinder(0.3, 0.6, 1.5), 0.05)
    system = DipoleSystem(lat, OPTICS.k, OPTICS.n_medium)
    with pytest.raises(ConvergenceError, match=r"relative residual .* after 2 iterations"):
        system.solve([0, 0, -1.0], [1.0, 0, 0], tol=1e-12, maxiter=2)
    sol = system.solve([0, 0, -1.0], [1.0, 0, 0], tol=1e-12, maxiter=2, raise_on_failure=False)
    assert sol.residual > 1e-12 and sol.iterations == 2


def test_warm_start_gives_the_same_answer_faster():
    model = Spherocylinder(0.35, 0.8, 1.495)
    cold_engine = BuiltinDDA(dipole_size_um=0.05, tolerance=1e-8)
    warm_engine = BuiltinDDA(dipole_size_um=0.05, tolerance=1e-8)
    warm_engine.solve(model, OPTICS, Orientation(0.5, 1.0, 0.0))
    warm_engine.solve(model, OPTICS, Orientation(0.51, 1.0, 0.0))
    target = Orientation(0.505, 1.004, 0.0)
    cold = cold_engine.solve(model, OPTICS, target)
    cold_its = cold_engine.last_iterations
    warm = warm_engine.solve(model, OPTICS, target)
    assert warm_engine.last_iterations < cold_its
    scale = np.abs(cold.solution.P).max()
    np.testing.assert_allclose(warm.solution.P, cold.solution.P, atol=1e-6 * scale)


def test_only_the_instrument_polarization_is_solved():
    eng = BuiltinDDA(dipole_size_um=0.05)
    wave = eng.solve(Spherocylinder(0.3, 0.6, 1.5), OPTICS, Orientation(0.2, 0.9, 0.0))
    system = next(iter(eng._systems.items()))[1]
    # one solve: the iterations plus the initial-residual product(s), not two polarisations
    assert system.matvecs <= wave.solution.iterations + 2


def test_bicgstab_gives_the_same_dipoles():
    model = Spherocylinder(0.3, 0.6, 1.5)
    ori = Orientation(0.3, 0.9, 0.0)
    qmr = BuiltinDDA(dipole_size_um=0.05, tolerance=1e-8).solve(model, OPTICS, ori)
    bicg = BuiltinDDA(dipole_size_um=0.05, tolerance=1e-8, solver="bicgstab").solve(
        model, OPTICS, ori)
    scale = np.abs(qmr.solution.P).max()
    np.testing.assert_allclose(bicg.solution.P, qmr.solution.P, atol=1e-6 * scale)


@pytest.mark.filterwarnings("error")
def test_warm_starts_across_sizes_and_indices_stay_finite():
    """A fit's initial pass changes sizes and index between solves: voxels whose
    polarisability is zero (all medium) must not turn the carried-over start into NaN."""
    warm_engine = BuiltinDDA(dipole_size_um=0.05, tolerance=1e-8)
    o = Orientation(0.5, 1.0, 0.0)
    for a, b, n in [(0.35, 0.8, 1.495), (0.36, 0.82, 1.5), (0.34, 0.78, 1.49),
                    (0.35, 0.8, 1.3301), (0.35, 0.8, OPTICS.n_medium)]:
        model = Spherocylinder(a, b, n)
        warm = warm_engine.solve(model, OPTICS, o)
        cold = BuiltinDDA(dipole_size_um=0.05, tolerance=1e-8).solve(model, OPTICS, o)
        scale = max(np.abs(cold.solution.P).max(), 1e-300)
        assert np.all(np.isfinite(warm.solution.P))
        np.testing.assert_allclose(warm.solution.P, cold.solution.P, atol=1e-6 * scale)


def test_a_start_that_is_not_a_number_fails_at_once():
    rng = np.random.default_rng(1)
    n = 40
    a = rng.normal(size=(n, n)) + 1j * rng.normal(size=(n, n))
    a = a + a.T + 20 * np.eye(n)
    b = rng.normal(size=n) + 0j
    x0 = np.full(n, np.nan + 0j)
    result = qmr_cs(lambda v: a @ v, b, tol=1e-10, maxiter=500, x0=x0)
    assert not result.converged and result.iterations <= 1
