"""The ADDA engine end to end with a stand-in executable (tests/stubs/fake_adda.py).

The stand-in writes the first-Born-approximation amplitude matrix of the dipole set it is given,
computed in ADDA's own conventions (light along ADDA +z, -orient about the box centre, phase
origin at the box centre). The adapter's result must equal the same Born sum done directly in
holofit's lab frame about the particle centre: this checks the shape file, the pairs file, the
command line, row order, polarisation, phase origin and frames together. The stand-in's other
modes exercise the failure paths (non-zero exit, ERROR, -maxiter warning, bad output).
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
import warnings
from pathlib import Path

import numpy as np
import pytest

from holofit.conventions import DetectorGrid, euler_zyz, hologram_intensity
from holofit.dda import adda as ae
from holofit.engines.registry import get_engine
from holofit.hologram import calc_hologram
from holofit.optics import Optics
from holofit.particles import JanusSphere, Spherocylinder
from holofit.scattering.theory import Orientation

STUB = Path(__file__).parent / "stubs" / "fake_adda.py"
OPTICS = Optics(0.66, 1.33, 0.4)
JANUS = JanusSphere(0.3, 0.06, 1.59, 2.7)
ROD = Spherocylinder(0.2, 0.5, 1.45)
D = 0.05


def make_stub(folder: Path, name: str = "adda") -> Path:
    """An executable that runs the stand-in with this interpreter (numpy available)."""
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / name
    path.write_text(f'#!/bin/sh\nexec "{sys.executable}" "{STUB}" "$@"\n')
    path.chmod(0o755)
    return path


@pytest.fixture
def stub(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    monkeypatch.delenv(ae.ADDA_ENV_VAR, raising=False)
    monkeypatch.setenv("FAKE_ADDA_CALLS", str(tmp_path / "calls.jsonl"))
    monkeypatch.delenv("FAKE_ADDA_MODE", raising=False)
    return make_stub(tmp_path / "bin")


def calls(tmp_path: Path) -> list[dict]:
    path = tmp_path / "calls.jsonl"
    return [json.loads(line) for line in path.read_text().splitlines()] if path.exists() else []


def born_reference(engine: ae.AddaEngine, model, orientation: Orientation,
                   directions: np.ndarray) -> np.ndarray:
    """First Born approximation in holofit's lab, about the particle centre (no ADDA frame)."""
    lat = engine.lattice(model, OPTICS)
    keep = lat.fractions.sum(axis=1) >= 0.5
    pos = lat.positions[keep] @ euler_zyz(*orientation.as_tuple()).T
    m = np.array([complex(n) / OPTICS.n_medium for n in lat.indices])
    alpha = (3 * lat.d**3 / (4 * np.pi) * (m**2 - 1) / (m**2 + 2))[
        np.argmax(lat.fractions[keep], axis=1)]
    k = OPTICS.k
    a = np.array([0.0, 0.0, -1.0])
    s = np.exp(1j * k * ((a[None, :] - directions) @ pos.T)) @ alpha
    e = OPTICS.polarization
    e_perp = e[None, :] - directions * (directions @ e)[:, None]
    return -1j * k**3 * e_perp * s[:, None]


def detector_directions(position: tuple[float, float, float], grid: DetectorGrid) -> np.ndarray:
    x, y = grid.coordinates()
    pts = np.stack([x.ravel() - position[0], y.ravel() - position[1],
                    np.full(x.size, -position[2])], axis=1)
    return pts / np.linalg.norm(pts, axis=1, keepdims=True)


# -- finding the binary ----------------------------------------------------------------------


def test_find_adda_order_explicit_env_path(tmp_path: Path, monkeypatch) -> None:
    explicit = make_stub(tmp_path / "a")
    from_env = make_stub(tmp_path / "b")
    on_path = make_stub(tmp_path / "c")
    monkeypatch.setenv("PATH", str(on_path.parent) + os.pathsep + os.environ.get("PATH", ""))
    monkeypatch.setenv(ae.ADDA_ENV_VAR, str(from_env))
    assert ae.find_adda(explicit) == explicit.resolve()
    assert ae.find_adda() == from_env.resolve()
    monkeypatch.delenv(ae.ADDA_ENV_VAR)
    assert ae.find_adda() == on_path.resolve()


def test_missing_binary_is_a_clear_error(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.delenv(ae.ADDA_ENV_VAR, raising=False)
    monkeypatch.setenv("PATH", str(tmp_path))
    with pytest.raises(ae.AddaNotFoundError, match=r"no ADDA binary found.*HOLOFIT_ADDA.*PATH"):
        ae.find_adda()
    with pytest.raises(ae.AddaNotFoundError, match="no ADDA binary found"):
        get_engine("adda")
    with pytest.raises(ae.AddaNotFoundError, match=r"adda_path = '/no/such/adda'"):
        ae.AddaEngine(adda_path="/no/such/adda")
    monkeypatch.setenv(ae.ADDA_ENV_VAR, str(tmp_path / "missing"))
    with pytest.raises(ae.AddaNotFoundError, match="HOLOFIT_ADDA"):
        ae.find_adda()


def test_registry_builds_the_adda_engine(stub: Path, monkeypatch) -> None:
    monkeypatch.setenv(ae.ADDA_ENV_VAR, str(stub))
    engine = get_engine("adda", dipole_size_um=D, tolerance=1e-6)
    assert isinstance(engine, ae.AddaEngine) and engine.name == "adda"
    assert engine.settings.dipole_size_um == D and engine.settings.tolerance == 1e-6
    assert get_engine("adda", adda_path=str(stub)).binary == str(stub.resolve())


# -- version check ---------------------------------------------------------------------------


def test_version_is_checked_once_per_process(stub: Path, tmp_path: Path) -> None:
    grid = DetectorGrid((6, 6), 0.3)
    for _ in range(2):
        engine = ae.AddaEngine(adda_path=stub, dipole_size_um=D)
        assert engine.version.version == "1.5.0-alpha3" and engine.version.tested
        wave = engine.solve(ROD, OPTICS, Orientation(0.2, 0.3, 0.0))
        wave.field_on_detector((1.0, 1.0, 5.0), grid, far_field=True)
    argv = [c["argv"] for c in calls(tmp_path)]
    assert argv.count(["-V"]) == 1
    assert len(argv) == 3  # one version check, two runs


def test_untested_and_bogus_versions(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setenv("FAKE_ADDA_VERSION", "ADDA v.1.3b4")
    old = make_stub(tmp_path / "old")
    with pytest.warns(ae.AddaWarning, match=r"1\.3b4 .* not a version holofit was tested"):
        info = ae.adda_version(str(old))
    assert info.numbers == (1, 3) and not info.tested
    monkeypatch.setenv("FAKE_ADDA_VERSION", "hello, I am not ADDA")
    with pytest.raises(ae.AddaError, match="did not print an ADDA version banner"):
        ae.adda_version(str(make_stub(tmp_path / "bogus")))
    info = ae.parse_version("ADDA v.1.5.0-alpha3 (acbebb0)\nSequential version\n")
    assert (info.version, info.commit, info.tested) == ("1.5.0-alpha3", "acbebb0", True)


# -- the whole pipeline against an independent Born sum --------------------------------------


@pytest.mark.parametrize(
    "model, orientation",
    [
        (JANUS, Orientation(0.3, 0.0, 0.0)),
        (JANUS, Orientation(0.3, np.pi, 0.0)),
        (JANUS, Orientation(-1.1, 0.9, 2.0)),
        (ROD, Orientation(0.5, 1.0, 0.3)),
    ],
)
def test_adapter_reproduces_born_sum_in_our_frame(stub: Path, model, orientation) -> None:
    engine = ae.AddaEngine(adda_path=stub, dipole_size_um=D)
    grid = DetectorGrid((12, 10), 0.4, corner=(3, 5))
    position = (4.0, 3.5, 6.0)
    n = detector_directions(position, grid)
    wave = engine.solve(model, OPTICS, orientation)
    f = wave.far_field_amplitude(n)
    ref = born_reference(engine, model, orientation, n)
    assert np.abs(f - ref).max() < 1e-8 * np.abs(ref).max()
    # the field on the detector: exp(ikr)/(-ikr) F with the incident phase at the particle
    ex, ey = wave.field_on_detector(position, grid, far_field=True)
    x, y = grid.coordinates()
    r = np.sqrt((x - position[0]) ** 2 + (y - position[1]) ** 2 + position[2] ** 2).ravel()
    k = OPTICS.k
    e_ref = ref * (np.exp(1j * k * r) / (-1j * k * r) * np.exp(-1j * k * position[2]))[:, None]
    np.testing.assert_allclose(ex.ravel(), e_ref[:, 0], rtol=0, atol=1e-8 * np.abs(e_ref).max())
    np.testing.assert_allclose(ey.ravel(), e_ref[:, 1], rtol=0, atol=1e-8 * np.abs(e_ref).max())
    assert engine.runs == 1  # same directions: cached


def test_janus_born_differs_between_cap_up_and_down(stub: Path) -> None:
    """The stand-in test can tell a mirrored frame: theta = 0 and pi differ at the detector."""
    engine = ae.AddaEngine(adda_path=stub, dipole_size_um=D)
    n = detector_directions((2.0, 2.0, 6.0), DetectorGrid((8, 8), 0.5))
    up = engine.solve(JANUS, OPTICS, Orientation(0.0, 0.0, 0.0)).far_field_amplitude(n)
    down = engine.solve(JANUS, OPTICS, Orientation(0.0, np.pi, 0.0)).far_field_amplitude(n)
    assert np.abs(up - down).max() > 1e-2 * np.abs(up).max()


def test_hologram_says_it_is_far_field(stub: Path) -> None:
    engine = ae.AddaEngine(adda_path=stub, dipole_size_um=D)
    wave = engine.solve(ROD, OPTICS, Orientation(0.5, 1.0, 0.3))
    assert wave.exact_near_field is False
    assert "far-field" in wave.description and "exp(ikr)/(-ikr)" in wave.description
    grid = DetectorGrid((10, 10), 0.3)
    with pytest.warns(ae.AddaFarFieldWarning, match="near field is not available"):
        holo = calc_hologram(wave, (1.5, 1.5, 5.0), grid, alpha=0.9)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        again = calc_hologram(wave, (1.5, 1.5, 5.0), grid, alpha=0.7)  # warned once; cached
    n = detector_directions((1.5, 1.5, 5.0), grid)
    x, y = grid.coordinates()
    r = np.sqrt((x - 1.5) ** 2 + (y - 1.5) ** 2 + 25.0).ravel()
    k = OPTICS.k
    e = born_reference(engine, ROD, Orientation(0.5, 1.0, 0.3), n) * (
        np.exp(1j * k * r) / (-1j * k * r) * np.exp(-1j * k * 5.0))[:, None]
    ref = hologram_intensity(e[:, 0].reshape(10, 10), e[:, 1].reshape(10, 10), 0.4, 0.9)
    np.testing.assert_allclose(holo, ref, atol=1e-9)
    assert engine.runs == 1 and not np.allclose(again, holo)
    meta = wave.metadata
    assert meta["engine"] == "adda" and meta["adda_version"] == "1.5.0-alpha3"
    assert "-scat_grid_inp" in meta["last_command"]


def test_each_run_has_its_own_temporary_directory_removed_afterwards(stub: Path,
                                                                    tmp_path: Path) -> None:
    engine = ae.AddaEngine(adda_path=stub, dipole_size_um=D, tolerance=1e-6, max_iterations=77)
    wave = engine.solve(ROD, OPTICS, Orientation(0.1, 0.2, 0.3))
    for z in (5.0, 6.0):
        wave.field_on_detector((1.0, 1.0, z), DetectorGrid((4, 4), 0.5), far_field=True)
    runs = [c for c in calls(tmp_path) if c["argv"] != ["-V"]]
    assert len(runs) == 2 and runs[0]["cwd"] != runs[1]["cwd"]
    for c in runs:
        cwd = Path(c["cwd"])
        assert cwd.name.startswith("holofit-adda-")
        assert cwd.parent == Path(tempfile.gettempdir()).resolve() or str(cwd).startswith(
            tempfile.gettempdir())
        assert not cwd.exists()
        argv = c["argv"]
        assert argv[argv.index("-eps") + 1] == "6.0"
        assert argv[argv.index("-maxiter") + 1] == "77"
    assert wave.last_run is not None and wave.last_run.workdir is None


# -- failures are loud -----------------------------------------------------------------------


def _evaluate(stub: Path) -> None:
    engine = ae.AddaEngine(adda_path=stub, dipole_size_um=D)
    wave = engine.solve(ROD, OPTICS, Orientation(0.0, 0.5, 0.0))
    wave.field_on_detector((1.0, 1.0, 5.0), DetectorGrid((4, 4), 0.5), far_field=True)


def test_nonzero_exit_raises_with_message_and_command(stub: Path, monkeypatch) -> None:
    monkeypatch.setenv("FAKE_ADDA_MODE", "exit")
    with pytest.raises(ae.AddaError, match=r"(?s)status 3: stand-in crashed: out of memory"
                                           r".*command: .*-shape read shape\.dat"):
        _evaluate(stub)


def test_error_on_stderr_raises_even_with_exit_0(stub: Path, monkeypatch) -> None:
    monkeypatch.setenv("FAKE_ADDA_MODE", "error")
    with pytest.raises(ae.AddaError, match=r"(?s)reported an error: ERROR: .*Failed to open "
                                           r"file 'shape\.dat'.*command: .*-scat_matr ampl"):
        _evaluate(stub)


def test_maxiter_warning_raises_convergence_error(stub: Path, monkeypatch) -> None:
    monkeypatch.setenv("FAKE_ADDA_MODE", "maxiter")
    with pytest.raises(ae.AddaConvergenceError,
                       match=r"(?s)haven't converged in 3 iterations\. Further calculated.*"
                             r"command: .*-maxiter"):
        _evaluate(stub)


def test_other_adda_warnings_are_passed_on(stub: Path, monkeypatch) -> None:
    monkeypatch.setenv("FAKE_ADDA_MODE", "warn")
    with pytest.warns(ae.AddaWarning, match="a harmless stand-in warning"):
        _evaluate(stub)


def test_bad_output_is_an_error(stub: Path, monkeypatch) -> None:
    monkeypatch.setenv("FAKE_ADDA_MODE", "shuffle")
    with pytest.raises(ae.AddaError, match=r"(?s)not in the requested order.*command:"):
        _evaluate(stub)
    monkeypatch.setenv("FAKE_ADDA_MODE", "noampl")
    with pytest.raises(ae.AddaError, match="wrote no ampl_scatgrid"):
        _evaluate(stub)


def test_check_adda_output_on_real_adda_messages() -> None:
    """Messages as ADDA v1.5.0-alpha3 prints them (wrapped over two lines)."""
    cmd = ["adda", "-maxiter", "3"]
    real = ("WARNING: (../iterative.c:1630) Iterations haven't converged in 3 iterations.\n"
            "Further calculated scattering quantities may be less accurate.\n")
    with pytest.raises(ae.AddaConvergenceError, match="less accurate"):
        ae.check_adda_output(cmd, 0, " 33% 66% 100%  done\n", real)
    with pytest.raises(ae.AddaError, match=r"Failed to open file 'nofile\.geom'"):
        ae.check_adda_output(cmd, 1, "", "ERROR: (../make_particle.c:1061) Failed to open file "
                                         "'nofile.geom'\n")
    assert ae.check_adda_output(cmd, 0, "INFO: fine\nall data is saved in 'out'\n", "") == []
