"""Integration with a real ADDA binary (``HOLOFIT_ADDA`` or ``adda`` on PATH).

Skipped, with the reason shown by ``pytest -ra``, when no binary is found. Holograms from the
ADDA engine must agree with the built-in engine's far-field mode on the same dipoles (binary
filling, same dipole size) with R^2 >= 0.9999: the Janus particle with its cap toward the
source (theta = 0) and away from it (theta = pi), and the rod at a tilted orientation.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from holofit.conventions import DetectorGrid, r_squared
from holofit.dda import adda as ae
from holofit.dda.engine import BuiltinDDA
from holofit.hologram import calc_hologram
from holofit.optics import Optics
from holofit.particles import JanusSphere, Spherocylinder
from holofit.scattering.theory import Orientation

pytestmark = pytest.mark.adda

OPTICS = Optics(0.66, 1.33, 0.0)
GRID = DetectorGrid((140, 140), 0.1)
POSITION = (7.0, 7.0, 12.0)
JANUS = JanusSphere(0.439, 0.05, 1.59, 2.7)
ROD = Spherocylinder(0.5, 1.0, 1.495)


@pytest.fixture(scope="module")
def adda_binary() -> str:
    try:
        return str(ae.find_adda())
    except ae.AddaNotFoundError as exc:
        pytest.skip(f"ADDA integration tests need an ADDA binary: {exc}")


@pytest.fixture(scope="module")
def engine(adda_binary: str) -> ae.AddaEngine:
    return ae.AddaEngine(adda_path=adda_binary)


def test_real_adda_version(engine: ae.AddaEngine) -> None:
    info = engine.version
    assert info.numbers >= (1, 4), info.banner
    print(f"ADDA under test: {info.banner} at {info.binary} (tested: {info.tested})")


@pytest.mark.parametrize(
    "model, orientation, pol",
    [
        (JANUS, Orientation(0.4, 0.0, 0.0), 0.0),
        (JANUS, Orientation(0.4, np.pi, 0.0), 0.0),
        (ROD, Orientation(0.5, 1.0, 0.3), 0.0),
        (ROD, Orientation(0.5, 1.0, 0.3), 0.6),
    ],
    ids=["janus-theta0", "janus-thetapi", "rod-tilted", "rod-tilted-pol0.6"],
)
def test_adda_hologram_matches_builtin_far_field(engine: ae.AddaEngine, model,
                                                 orientation: Orientation, pol: float) -> None:
    """pol 0.6 rad: ADDA's lab is turned so that its X solution is the instrument's (the LDR
    polarisability depends on the polarisation; superposing X and Y would differ by ~3e-3)."""
    optics = Optics(OPTICS.wavelength_um, OPTICS.n_medium, pol)
    builtin = BuiltinDDA(filling="binary")
    assert builtin.dipole_size(model, optics) == engine.dipole_size(model, optics)
    wave_adda = engine.solve(model, optics, orientation)
    with pytest.warns(ae.AddaFarFieldWarning):
        holo_adda = calc_hologram(wave_adda, POSITION, GRID)
    wave_builtin = builtin.solve(model, optics, orientation)
    holo_builtin = calc_hologram(wave_builtin, POSITION, GRID, far_field=True)
    r2 = r_squared(holo_builtin, holo_adda)
    print(f"{model.kind} {orientation}: 1 - R^2 = {1 - r2:.2e}, {wave_adda.geometry.n_dipoles} "
          f"dipoles, "
          f"ADDA {wave_adda.last_run.seconds:.2f} s")
    assert r2 >= 0.9999
    # amplitudes too: both solvers stop at relative residual 1e-5
    n = np.array([[0.1, -0.2, -1.0], [0.0, 0.0, -1.0], [0.3, 0.25, -0.9]])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    f_adda = wave_adda.far_field_amplitude(n)
    f_builtin = wave_builtin.far_field_amplitude(n)
    assert np.abs(f_adda - f_builtin).max() < 1e-4 * np.abs(f_builtin).max()


def test_janus_cap_up_and_down_differ_in_adda_as_in_builtin(engine: ae.AddaEngine) -> None:
    """Cross-check of the frame with the real binary: ADDA's theta=0 is not the builtin's pi."""
    n = np.array([[np.sin(t), 0.0, -np.cos(t)] for t in np.radians([0, 5, 10, 15])])
    up = engine.solve(JANUS, OPTICS, Orientation(0.0, 0.0, 0.0)).far_field_amplitude(n)
    builtin = BuiltinDDA(filling="binary")
    down_b = builtin.solve(JANUS, OPTICS, Orientation(0.0, np.pi, 0.0)).far_field_amplitude(n)
    up_b = builtin.solve(JANUS, OPTICS, Orientation(0.0, 0.0, 0.0)).far_field_amplitude(n)
    scale = np.abs(up_b).max()
    assert np.abs(up - up_b).max() < 1e-4 * scale
    assert np.abs(up - down_b).max() > 1e-2 * scale


def test_real_adda_maxiter_is_an_error(adda_binary: str) -> None:
    engine = ae.AddaEngine(adda_path=adda_binary, max_iterations=2)
    wave = engine.solve(JANUS, OPTICS, Orientation(0.0, 0.5, 0.0))
    with pytest.raises(ae.AddaConvergenceError, match=r"(?s)converged in 2 iterations.*command:"):
        wave.far_field_amplitude(np.array([[0.0, 0.0, -1.0]]))


def test_real_adda_error_message_is_quoted(adda_binary: str, tmp_path) -> None:
    with pytest.raises(ae.AddaError, match=r"(?s)ERROR: .*nofile\.geom.*command: "):
        ae.run_adda(adda_binary, ["-shape", "read", "nofile.geom", "-size", "1"], tmp_path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(ae.AddaError, match="ERROR"):
            ae.run_adda(adda_binary, ["-no_such_option"], tmp_path)
