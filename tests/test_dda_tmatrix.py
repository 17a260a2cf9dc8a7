"""A particle's T-matrix from the DDA: exact against direct solves of the same lattice at every
orientation, physically consistent, differentiable, and safe to store.

References: direct DDA solves of the same lattice with the same (incidence-independent)
polarisability at tight tolerance, their central finite differences, energy conservation and
the optical theorem, reciprocity of the amplitude matrix, a build without symmetries.
Small particles on coarse lattices keep this fast; the paper's particles at 50 orientations
are in test_dda_tmatrix_slow.py.
"""

import json

import numpy as np
import pytest

from holofit.conventions import DetectorGrid, pixel_centres, r_squared
from holofit.dda.engine import BuiltinDDA
from holofit.dda.settings import DDASettings
from holofit.dda.tmatrix_build import BuildSettings, build_lattice_tmatrix, build_tmatrix
from holofit.dda.tmatrix_io import TMatrixMismatch, clear_cache, load_tmatrix, save_tmatrix
from holofit.dda.voxelize import voxelize
from holofit.hologram import calc_hologram
from holofit.io.shapefile import write_shape_file
from holofit.optics import Optics
from holofit.particles import Dimer, JanusSphere, Sphere, Spherocylinder, VoxelShape
from holofit.scattering.theory import Orientation
from holofit.scattering.tmatrix_wave import TMatrixWave
from holofit.scattering.vsw import plane_wave_coefficients

OPTICS = Optics(0.66, 1.33, np.radians(20))
GRID = DetectorGrid((60, 60), 0.15)
POS = (4.5, 4.4, 9.0)
D = 0.07
ROD = Spherocylinder(0.2, 0.45, 1.495)
MODELS = {
    "rod": ROD,
    "dimer": Dimer(0.17, 0.17, 0.03, 1.5, 1.5),
    "janus": JanusSphere(0.2, 0.06, 1.58, 2.7),
}


#: tight builds, so that these tests see the construction's exactness (the defaults, truncation
#: 3e-6 and solver 1e-6 in single precision, are checked in test_dda_tmatrix_slow.py)
TIGHT = {"tolerance": 1e-9, "truncation": 1e-7, "precision": "double"}


def _engine(tolerance=1e-10, polarizability="fcd"):
    """Direct solves at 1e-10; engines serving a tight T-matrix accept its 1e-9. The engine's
    default prescription (filtered coupled dipoles) unless another is asked for."""
    return BuiltinDDA(dipole_size_um=D, polarizability=polarizability, tolerance=tolerance)


@pytest.fixture(scope="module")
def voxel_model(tmp_path_factory):
    """An irregular voxel set (no lattice symmetry): the path with one solve per column."""
    rng = np.random.default_rng(5)
    lat = voxelize(Spherocylinder(0.11, 0.22, 1.5), D, "binary")
    keep = rng.uniform(size=lat.n_dipoles) < 0.8
    path = write_shape_file(tmp_path_factory.mktemp("vox") / "blob.geom", lat.ijk[keep],
                            domain=(lat.ijk[keep, 2] > 3).astype(int))
    return VoxelShape(str(path), D, (1.5, 1.6 + 0.02j))


@pytest.fixture(scope="module")
def engines(voxel_model):
    """name -> (model, engine serving from a T-matrix, engine solving directly)."""
    out = {}
    cases = {name: (m, "fcd") for name, m in {**MODELS, "voxels": voxel_model}.items()}
    cases["rod_ldr_avg"] = (ROD, "ldr_avg")
    for name, (model, pol) in cases.items():
        fast = _engine(TIGHT["tolerance"], pol)
        fast.tmatrix(model, OPTICS, **TIGHT)
        out[name] = (model, fast, _engine(polarizability=pol))
    return out


def _orientations(n, seed=0):
    rng = np.random.default_rng(seed)
    return [Orientation(*rng.uniform(0, 2 * np.pi, 3)) for _ in range(n)]


def _max_rel(a, b):
    return max(np.abs(x - y).max() for x, y in zip(a, b, strict=True)) / max(
        np.abs(y).max() for y in b)


@pytest.mark.parametrize("name", ["rod", "dimer", "janus", "voxels", "rod_ldr_avg"])
def test_holograms_and_far_fields_equal_direct_solves(engines, name):
    model, fast, direct = engines[name]
    tm = fast.tmatrix(model, OPTICS)
    assert tm.provenance["order"] >= 6
    assert tm.provenance["validation_far_field_error"] < 1e-6
    dirs = np.random.default_rng(1).normal(size=(50, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    for ori in _orientations(3):
        w_t, w_d = fast.solve(model, OPTICS, ori), direct.solve(model, OPTICS, ori)
        assert isinstance(w_t, TMatrixWave)
        fields = (w_t.field_on_detector(POS, GRID), w_d.field_on_detector(POS, GRID))
        assert _max_rel(*fields) <= 1e-6
        h_t, h_d = calc_hologram(w_t, POS, GRID), calc_hologram(w_d, POS, GRID)
        assert 1.0 - r_squared(h_d, h_t) <= 1e-10
        f_t, f_d = w_t.far_field_amplitude(dirs), w_d.far_field_amplitude(dirs)
        assert np.abs(f_t - f_d).max() <= 1e-6 * np.abs(f_d).max()


@pytest.mark.parametrize("model,d,ops", [
    (ROD, 0.09, 16),  # D4h: every operation permutes coefficients (monomial path)
    (Sphere(0.2, 1.5), 0.08, 48),  # Oh: 90-degree turns about x and y mix m (dense path)
])
def test_symmetry_build_equals_build_without_symmetry(model, d, ops):
    lat = voxelize(model, d)
    kw = dict(tolerance=1e-10, order=5, validate=False)
    sym, stats = build_lattice_tmatrix(lat, OPTICS.k, OPTICS.n_medium, "ldr_avg",
                                       BuildSettings(**kw))
    plain, plain_stats = build_lattice_tmatrix(lat, OPTICS.k, OPTICS.n_medium, "ldr_avg",
                                               BuildSettings(use_symmetry=False, **kw))
    assert stats.symmetry_operations == ops and plain_stats.symmetry_operations == 1
    assert stats.n_solves == -(-plain_stats.n_solves // ops)
    a, b = sym.dense(), plain.dense()
    assert np.abs(a - b).max() <= 1e-8 * np.abs(b).max()


def test_build_shared_by_two_processes_equals_the_build_in_one(monkeypatch):
    """The solves spread over worker processes (``workers``) give the same T-matrix: each
    design vector is solved alike wherever it runs; the chunks are put back in order."""
    import holofit.dda.tmatrix_build as tb

    monkeypatch.setattr(tb, "PARALLEL_MIN_WORK", 0)  # a small build, shared all the same
    lat = voxelize(MODELS["janus"], 0.08)
    kw = dict(tolerance=1e-8, order=5, validate=False, use_symmetry=False)
    one, one_stats = build_lattice_tmatrix(lat, OPTICS.k, OPTICS.n_medium, "fcd",
                                           BuildSettings(**kw))
    two, two_stats = build_lattice_tmatrix(lat, OPTICS.k, OPTICS.n_medium, "fcd",
                                           BuildSettings(workers=2, **kw))
    assert one_stats.n_solves == two_stats.n_solves > 8  # more than one chunk per worker
    assert one_stats.iterations == two_stats.iterations
    assert two.provenance["build_workers"] == 2 and one.provenance["build_workers"] == 1
    a, b = one.dense(), two.dense()
    assert np.abs(a - b).max() <= 1e-12 * np.abs(a).max()


def _scattering_cross_section(wave, k):
    """(1/k^2) int |F|^2 dOmega by Gauss-Legendre x uniform quadrature."""
    mu, w = np.polynomial.legendre.leggauss(60)
    phi = 2 * np.pi * np.arange(120) / 120
    st = np.sqrt(1 - mu**2)
    dirs = np.stack(np.broadcast_arrays(st[:, None] * np.cos(phi), st[:, None] * np.sin(phi),
                                        mu[:, None]), -1).reshape(-1, 3)
    f2 = np.sum(np.abs(wave.far_field_amplitude(dirs)) ** 2, axis=1).reshape(60, 120)
    return float(np.sum(w[:, None] * f2) * 2 * np.pi / 120) / k**2


@pytest.mark.parametrize("name", ["rod", "janus", "voxels"])
def test_optical_theorem(engines, name):
    """C_ext from the forward amplitude (T-matrix) = C_sca (T-matrix far field) + C_abs (the
    dipoles' absorption in a direct solve; zero for real indices)."""
    model, fast, direct = engines[name]
    k = OPTICS.k
    for ori in _orientations(2, seed=3):
        wave = fast.solve(model, OPTICS, ori)
        f = wave.far_field_amplitude(np.array([[0.0, 0.0, -1.0]]))[0]
        c_ext = 4 * np.pi / k**2 * np.real(np.dot(OPTICS.polarization, f))
        sol = direct.solve(model, OPTICS, ori).solution
        alpha = sol.alpha if sol.alpha.ndim == 2 else sol.alpha[:, None]  # laminate: per axis
        c_abs = 4 * np.pi * k * float(np.sum(
            np.imag(np.sum(sol.P * np.conj(sol.P / alpha), axis=1))
            - (2.0 / 3.0) * k**3 * np.sum(np.abs(sol.P) ** 2, axis=1)))
        c_sca = _scattering_cross_section(wave, k)
        assert c_ext == pytest.approx(c_sca + c_abs, rel=1e-7)
        if name != "voxels":  # real indices: no absorption
            assert abs(c_abs) < 1e-9 * c_ext


def test_reciprocity(engines):
    """e_s . F(k_s; k_i, e_i) = e_i . F(-k_i; -k_s, e_s) for the T-matrix's amplitudes."""
    model, fast, _ = engines["janus"]
    tm = fast.tmatrix(model, OPTICS)
    rng = np.random.default_rng(6)

    def amplitude(k_in, e_in, k_out, e_out):
        o = tm.scatter(plane_wave_coefficients(k_in, e_in, tm.order))
        return np.dot(e_out, -1j * tm.expansion(o).far_amplitude(k_out[None, :])[0])

    for _ in range(4):
        ki, ks = (v / np.linalg.norm(v) for v in rng.normal(size=(2, 3)))
        ei = np.cross(ki, rng.normal(size=3))
        es = np.cross(ks, rng.normal(size=3))
        ei, es = ei / np.linalg.norm(ei), es / np.linalg.norm(es)
        forward, backward = amplitude(ki, ei, ks, es), amplitude(-ks, es, -ki, ei)
        assert abs(forward - backward) <= 1e-7 * abs(forward)


@pytest.mark.parametrize("name", ["rod", "janus"])
def test_orientation_derivatives_equal_finite_differences_of_direct_solves(engines, name):
    model, fast, direct = engines[name]
    ori = Orientation(0.7, 1.2, -0.4)
    wave = fast.solve(model, OPTICS, ori)
    xs, ys = (c.ravel() for c in pixel_centres(GRID.shape, GRID.pixel_size_um))
    h = 1e-3
    for j, angle in enumerate(("psi", "theta", "phi")):
        vals = []
        for sign in (1, -1):
            a = list(ori.as_tuple())
            a[j] += sign * h
            vals.append(direct.solve(model, OPTICS, Orientation(*a)).field_on_pixels(
                POS, xs, ys))
        fd = [(p - m) / (2 * h) for p, m in zip(*vals, strict=True)]
        got = wave.orientation_derivative(angle).field_on_pixels(POS, xs, ys)
        assert _max_rel(got, fd) <= 1e-5
    axis = np.array([0.6, -0.3, 0.74])
    axis /= np.linalg.norm(axis)
    vals = []
    for sign in (1, -1):
        kx = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
        r = (np.eye(3) + np.sin(sign * h) * kx + (1 - np.cos(sign * h)) * kx @ kx) @ wave.rotation
        from holofit.conventions import euler_zyz_from_matrix

        o = Orientation(*(float(v) for v in euler_zyz_from_matrix(r)))
        vals.append(direct.solve(model, OPTICS, o).field_on_pixels(POS, xs, ys))
    fd = [(p - m) / (2 * h) for p, m in zip(*vals, strict=True)]
    assert _max_rel(wave.rotation_derivative(axis).field_on_pixels(POS, xs, ys), fd) <= 1e-5


def test_near_zone_uses_a_direct_solve(engines):
    model, fast, direct = engines["rod"]
    ori = Orientation(0.3, 0.9, 0.1)
    pts = np.array([[0.1, 0.2, -0.6], [0.5, -0.1, 0.2]])  # inside 2 circumscribing radii
    got = fast.solve(model, OPTICS, ori).field_at(pts)
    ref = direct.solve(model, OPTICS, ori).field_at(pts)
    assert np.abs(got - ref).max() <= 1e-7 * np.abs(ref).max()


def test_ldr_has_no_tmatrix():
    with pytest.raises(ValueError, match="ldr_avg"):
        build_tmatrix(ROD, OPTICS, DDASettings(dipole_size_um=D, polarizability="ldr"))
    assert DDASettings.from_dict({"polarizability": "ldr_avg"}).polarizability == "ldr_avg"


# -- files ------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def rod_file(engines, tmp_path_factory):
    model, fast, _ = engines["rod"]
    return save_tmatrix(fast.tmatrix(model, OPTICS), tmp_path_factory.mktemp("tm") / "rod.npz")


def test_file_roundtrip_and_provenance(engines, rod_file):
    model, fast, _ = engines["rod"]
    tm = fast.tmatrix(model, OPTICS)
    clear_cache()
    back = load_tmatrix(rod_file)
    assert load_tmatrix(rod_file) is back  # a worker reads a file once
    assert np.array_equal(back.dense(), tm.dense())
    assert (back.order, back.k, back.radius_um, back.modulus) == (
        tm.order, tm.k, tm.radius_um, tm.modulus)
    prov = json.loads((rod_file.parent / (rod_file.name + ".json")).read_text())
    for key in ("model", "dipole_size_um", "wavelength_um", "n_medium", "polarizability",
                "filling", "tolerance", "order", "truncation_estimate", "holofit_version",
                "lattice_fingerprint", "n_solves"):
        assert key in prov
    assert prov["model"]["parameters"]["a_um"] == ROD.a_um


def test_engine_loads_a_matching_file_instead_of_building(rod_file):
    engine = _engine(TIGHT["tolerance"])
    tm = engine.tmatrix(ROD, OPTICS, path=str(rod_file))
    assert tm is load_tmatrix(rod_file)
    assert engine.last_iterations == 0  # nothing solved
    wave = engine.solve(ROD, Optics(0.66, 1.33, 1.0), Orientation(0.2, 0.3))  # any polarisation
    assert isinstance(wave, TMatrixWave)


@pytest.mark.parametrize("engine_kw,model,optics,field", [
    ({}, ROD.replace(b_um=0.46), OPTICS, "model parameter b_um"),
    ({}, ROD, Optics(0.532, 1.33), "wavelength_um"),
    ({}, ROD, Optics(0.66, 1.34), "n_medium"),
    ({"polarizability": "ldr_avg"}, ROD, OPTICS, "polarizability"),
    ({"filling": "binary"}, ROD, OPTICS, "filling"),
    ({"dipole_size_um": 0.06}, ROD, OPTICS, "dipole_size_um"),
    ({"tolerance": 1e-12}, ROD, OPTICS, "tolerance"),
])
def test_a_file_for_anything_else_is_refused(rod_file, engine_kw, model, optics, field):
    kw = {"dipole_size_um": D, "tolerance": 1e-9, **engine_kw}
    engine = BuiltinDDA(**kw)
    with pytest.raises(TMatrixMismatch, match=field) as info:
        engine.tmatrix(model, optics, path=str(rod_file))
    assert str(rod_file) in str(info.value)


def test_incidence_independent_prescriptions_against_mie():
    """A T-matrix needs a polarisability that does not depend on the incident wave. The
    engine's default, the filtered coupled dipoles, is one and is more accurate than LDR;
    LDR with its S term averaged stays within a few times LDR; Clausius-Mossotti is worst
    (Lorenz-Mie as the truth; bench/polarizability_vs_mie.py has the full table)."""
    from holofit.scattering.mie import LorenzMie

    sphere = Sphere(0.3, 1.585)
    grid, pos = DetectorGrid((80, 80), 0.1), (4.0, 4.0, 8.0)
    exact = calc_hologram(LorenzMie().solve(sphere, OPTICS), pos, grid)
    misfit = {}
    for kind in ("ldr", "fcd", "ldr_avg", "cm"):
        for name, ori in (("axis", Orientation()), ("diagonal", Orientation(0.79, 0.96))):
            wave = BuiltinDDA(polarizability=kind, tolerance=1e-8).solve(sphere, OPTICS, ori)
            misfit[kind, name] = 1.0 - r_squared(exact, calc_hologram(wave, pos, grid))
    for name in ("axis", "diagonal"):
        assert misfit["fcd", name] <= misfit["ldr", name]
        assert misfit["ldr_avg", name] <= 4.0 * misfit["ldr", name]
        assert misfit["cm", name] > 3 * max(misfit["ldr_avg", name], misfit["fcd", name])


def test_fit_forward_model_gets_exact_orientation_columns(engines):
    """holofit.holomodel's HologramModel takes its orientation columns from the T-matrix wave's
    rotation derivatives; they equal central differences of direct solves."""
    from holofit.conventions import euler_zyz
    from holofit.holomodel.forward import HologramModel
    from holofit.holomodel.parameters import ParameterSpace, State, static_values

    model, fast, direct = engines["rod"]
    xs, ys = (c.ravel() for c in pixel_centres(GRID.shape, GRID.pixel_size_um))
    start = State(position=POS, rotation=euler_zyz(0.7, 1.1, 0.3), alpha=0.9,
                  statics=static_values(model))
    space = ParameterSpace(model, ["x_um", "orientation", "alpha"], start, fit_spin=True)
    v0 = space.initial_vector()
    analytic = HologramModel(fast, space, OPTICS, xs, ys).jacobian(v0)
    reference = HologramModel(direct, space, OPTICS, xs, ys)
    h = 1e-3
    for i, name in enumerate(space.names):
        if not name.startswith("rot_"):
            continue
        up, down = v0.copy(), v0.copy()
        up[i] += h
        down[i] -= h
        fd = (reference.hologram(up) - reference.hologram(down)) / (2 * h)
        assert np.abs(analytic[:, i] - fd).max() <= 1e-5 * np.abs(fd).max()


def test_default_build_meets_the_hologram_criteria():
    """Defaults (truncation estimate 3e-6, solver 1e-6, single-precision convolution):
    max|dE|/max|E| <= 1e-5 and 1 - R^2 <= 1e-8 against direct solves at 1e-8."""
    model = MODELS["dimer"]
    fast = BuiltinDDA(dipole_size_um=D)
    tm = fast.tmatrix(model, OPTICS)
    assert tm.provenance["build_precision"] == "single"
    assert tm.provenance["tolerance"] == 1e-6
    assert tm.provenance["polarizability"] == "fcd"
    direct = BuiltinDDA(dipole_size_um=D, tolerance=1e-8)
    for ori in _orientations(3, seed=4):
        w_t, w_d = fast.solve(model, OPTICS, ori), direct.solve(model, OPTICS, ori)
        assert _max_rel(w_t.field_on_detector(POS, GRID), w_d.field_on_detector(POS, GRID)) <= 1e-5
        assert 1 - r_squared(calc_hologram(w_d, POS, GRID), calc_hologram(w_t, POS, GRID)) <= 1e-8


def test_field_and_rotation_derivatives_in_one_pass(engines):
    model, fast, _ = engines["janus"]
    wave = fast.solve(model, OPTICS, Orientation(0.4, 2.0, 0.3))
    xs, ys = (c.ravel() for c in pixel_centres(GRID.shape, GRID.pixel_size_um))
    axes = [np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.6, 0.8])]
    for pos in (POS, (4.5, 4.4, 0.5)):  # the second has pixels in the near zone
        (ex, ey), derivs = wave.field_and_rotation_derivatives(pos, xs, ys, axes)
        ref = wave.field_on_pixels(pos, xs, ys)
        assert np.abs(ex - ref[0]).max() <= 1e-12 * np.abs(ref[0]).max()
        assert np.abs(ey - ref[1]).max() <= 1e-12 * np.abs(ref[0]).max()
        for axis, (dx, dy) in zip(axes, derivs, strict=True):
            # separately, the derivative wave picks its own grid margin: equal to the
            # interpolation's accuracy
            one = wave.rotation_derivative(axis).field_on_pixels(pos, xs, ys)
            scale = np.abs(one[0]).max()
            assert np.abs(dx - one[0]).max() <= 1e-9 * scale
            assert np.abs(dy - one[1]).max() <= 1e-9 * scale


def test_holograms_through_the_objective_lens(engines):
    """The lens image (finite NA) is built from the wave's expansion: a T-matrix wave gives the
    direct solve's, above and below the focal plane (one T-matrix serves every NA)."""
    from holofit.scattering.recorded_field import recorded_field

    model, fast, direct = engines["rod"]
    lens = Optics(OPTICS.wavelength_um, OPTICS.n_medium, OPTICS.polarization_rad,
                  numerical_aperture=1.2)
    xs, ys = (c.ravel() for c in pixel_centres(GRID.shape, GRID.pixel_size_um))
    ori = Orientation(0.7, 1.1, 0.2)
    w_t, w_d = fast.solve(model, lens, ori), direct.solve(model, lens, ori)
    assert isinstance(w_t, TMatrixWave)
    for z in (9.0, -3.0):
        got = recorded_field(w_t, (4.5, 4.4, z), xs, ys)
        assert _max_rel(got, recorded_field(w_d, (4.5, 4.4, z), xs, ys)) <= 1e-6
