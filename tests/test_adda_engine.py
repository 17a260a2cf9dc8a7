"""The ADDA adapter's seams, checked against recorded ADDA output (no ADDA needed).

The recorded runs (tests/data/adda, ADDA v1.5.0-alpha3) are re-expressed as holofit problems:
same dipoles, holofit orientation chosen so that the adapter's own ADDA input is equivalent to
the recorded one. The adapter's conversion of the recorded ``ampl_scatgrid`` (parser, amplitude
basis, phase-origin correction, frame mapping) must then reproduce the built-in engine's
far-field amplitudes. The Janus particle is not symmetric along z, so a mirrored frame or a
missing phase-origin correction shows at once.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial import cKDTree

from holofit.conventions import euler_zyz, euler_zyz_from_matrix, rotation_y, rotation_z
from holofit.dda import adda as ae
from holofit.dda.adda.frames import adda_amplitude_matrix
from holofit.dda.engine import BuiltinDDA
from holofit.dda.voxelize import voxelize
from holofit.io.shapefile import read_shape_file
from holofit.optics import Optics
from holofit.particles import JanusSphere, Spherocylinder, VoxelShape
from holofit.scattering.theory import Orientation
from tests.conftest import DATA

ADDA_DATA = DATA / "adda"
CASES = json.loads((ADDA_DATA / "cases.json").read_text())
GEOMS = {
    "a_sphere_r0.45": "a_sphere_r0.45/sphere.geom",
    "c_capsule_o0_0_0": "c_capsule_o0_0_0/capsule.geom",
    "c_capsule_o30_60_0": "c_capsule_o0_0_0/capsule.geom",
    "d_janus_o0_0_0": "d_janus_o0_0_0/janus_d0.024.geom",
}
N_MEDIUM = 1.33
WAVELENGTH = 0.66


def grid_angles() -> tuple[np.ndarray, np.ndarray]:
    """The directions of scat_grid_small.dat in ADDA's row order (theta outer, phi inner)."""
    text = (ADDA_DATA / "scat_grid_small.dat").read_text()
    assert "N=41" in text and "N=36" in text and "max=350" in text
    return np.repeat(np.linspace(0.0, 20.0, 41), 36), np.tile(np.arange(36) * 10.0, 41)


def adda_dirs(theta_deg: np.ndarray, phi_deg: np.ndarray) -> np.ndarray:
    th, ph = np.radians(theta_deg), np.radians(phi_deg)
    return np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], axis=1)


def recorded_problem(name: str) -> tuple[VoxelShape, Orientation, np.ndarray]:
    """holofit model and orientation equivalent to a recorded run, and ADDA's matrix R_A."""
    case = CASES[name]
    centre = tuple(case.get("sphere_centre_particle_frame_um", (0.0, 0.0, 0.0)))
    model = VoxelShape(str(ADDA_DATA / GEOMS[name]), case["dipole_size_um"],
                       tuple(m * N_MEDIUM for m in case["m_rel"]), centre)
    r_adda = euler_zyz(*np.radians(case["orient_deg"]))
    # ADDA lab = T holofit lab; the file's frame is the ADDA particle frame, so R = T R_A
    orientation = Orientation(*(float(v) for v in euler_zyz_from_matrix(ae.T_LAB @ r_adda)))
    return model, orientation, r_adda


def recorded_ampl(name: str) -> np.ndarray:
    th, ph = grid_angles()
    return ae.read_ampl_scatgrid(ADDA_DATA / name / "ampl_scatgrid", th, ph)


def rel_err(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.abs(a - b).max() / np.abs(b).max())


# -- angles and frames -----------------------------------------------------------------------


def test_euler_angles_of_adda_rotations_round_trip_including_gimbal_lock() -> None:
    rng = np.random.default_rng(1)
    angles = [tuple(rng.uniform(-np.pi, np.pi, 3)) for _ in range(50)]
    angles += [(0.3, 0.0, 0.5), (0.3, np.pi, 0.5), (-2.0, np.pi, 1.0), (0.0, 0.0, 0.0)]
    for psi, theta, phi in angles:
        rot = euler_zyz(psi, theta, phi)
        a, b, g = (float(v) for v in euler_zyz_from_matrix(rot))
        assert 0.0 <= b <= np.pi
        np.testing.assert_allclose(euler_zyz(a, b, g), rot, atol=1e-12)


def test_adda_orientation_is_T_R_T_and_a_zyz_triple_of_negated_angles() -> None:
    rng = np.random.default_rng(2)
    for _ in range(30):
        psi, theta, phi = rng.uniform(-np.pi, np.pi, 3)
        o = Orientation(psi, theta, phi)
        r_adda = euler_zyz(*np.radians(ae.adda_orientation_deg(o)))
        np.testing.assert_allclose(r_adda, ae.T_LAB @ euler_zyz(psi, theta, phi) @ ae.T_LAB,
                                   atol=1e-12)
        closed = rotation_z(-psi) @ rotation_y(-theta) @ rotation_z(-phi)
        np.testing.assert_allclose(r_adda, closed, atol=1e-12)
        beta = rng.uniform(-np.pi, np.pi)
        r_pol = euler_zyz(*np.radians(ae.adda_orientation_deg(o, beta)))
        np.testing.assert_allclose(r_pol, ae.lab_map(beta) @ euler_zyz(psi, theta, phi)
                                   @ ae.T_LAB, atol=1e-12)


@pytest.mark.parametrize("beta", [0.0, 0.4, np.pi / 2, -2.0])
def test_lab_map_puts_our_polarisation_on_addas_x_and_light_on_addas_z(beta: float) -> None:
    m = ae.lab_map(beta)
    np.testing.assert_allclose(m @ Optics(0.66, 1.33, beta).polarization, [1.0, 0, 0],
                               atol=1e-15)
    np.testing.assert_allclose(m @ np.array([0.0, 0.0, -1.0]), [0, 0, 1.0], atol=1e-15)
    assert np.linalg.det(m) == pytest.approx(1.0)


def test_T_maps_our_light_and_polarisation_onto_addas() -> None:
    np.testing.assert_allclose(ae.T_LAB @ np.array([0.0, 0.0, -1.0]), [0.0, 0.0, 1.0])
    np.testing.assert_allclose(ae.T_LAB @ np.array([1.0, 0.0, 0.0]), [1.0, 0.0, 0.0])
    assert np.linalg.det(ae.T_LAB) == pytest.approx(1.0)  # a rotation, not a mirror


@pytest.mark.parametrize("theta, cap_sign", [(0.0, -1.0), (np.pi, 1.0), (np.pi / 2, 0.0)])
def test_janus_cap_seen_by_adda_points_where_our_cap_points(theta: float, cap_sign: float) -> None:
    """theta = 0: cap toward the source, which is ADDA's -z (its light travels along +z)."""
    model = JanusSphere(0.439, 0.05, 1.59, 2.7)
    geom = ae.adda_geometry(voxelize(model, 0.04, "binary"))
    o = Orientation(0.7, theta, 0.2)
    r_adda = euler_zyz(*np.radians(ae.adda_orientation_deg(o)))
    pos = geom.positions_adda() @ r_adda.T
    cap = pos[geom.domain == 2].mean(axis=0) - pos[geom.domain == 1].mean(axis=0)
    cap /= np.linalg.norm(cap)
    # the same direction in ADDA's lab as our cap axis R z_hat mapped by T
    expected = ae.T_LAB @ euler_zyz(0.7, theta, 0.2) @ np.array([0.0, 0.0, 1.0])
    np.testing.assert_allclose(cap, expected, atol=1e-9)
    assert np.sign(round(cap[2], 6)) == cap_sign


def test_lab_to_adda_angles() -> None:
    n = np.array([[0, 0, -1.0], [1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0], [0.6, 0.0, -0.8]])
    theta, phi = ae.lab_to_adda_angles(n)
    np.testing.assert_allclose(theta, [0, 90, 90, 180, np.degrees(np.arccos(0.8))], atol=1e-12)
    np.testing.assert_allclose(phi[1:3], [0.0, 270.0], atol=1e-12)
    rng = np.random.default_rng(3)
    v = rng.normal(size=(100, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    th, ph = ae.lab_to_adda_angles(v)
    np.testing.assert_allclose(adda_dirs(th, ph) @ ae.T_LAB, v, atol=1e-12)


def test_amplitude_vectors_invert_adda_definition_of_S() -> None:
    """S1..S4 from known F_X, F_Y (holofit.dda.farfield's ADDA formulas) give back F for any
    incident polarisation, and the README's x-polarised formula."""
    rng = np.random.default_rng(4)
    th = rng.uniform(0, 180, 200)
    ph = rng.uniform(0, 360, 200)
    n = adda_dirs(th, ph)

    def transverse(f: np.ndarray) -> np.ndarray:
        return f - n * np.sum(n * f, axis=1, keepdims=True)

    fx = transverse(rng.normal(size=(200, 3)) + 1j * rng.normal(size=(200, 3)))
    fy = transverse(rng.normal(size=(200, 3)) + 1j * rng.normal(size=(200, 3)))
    s = adda_amplitude_matrix(fx, fy, np.radians(th), np.radians(ph))
    pols = ([1.0, 0, 0], [0, 1.0, 0], [np.cos(0.4), np.sin(0.4), 0], [2**-0.5, 1j * 2**-0.5, 0])
    for e in pols:
        e = np.asarray(e, dtype=complex)
        np.testing.assert_allclose(ae.amplitude_vectors(s, th, ph, e), e[0] * fx + e[1] * fy,
                                   atol=1e-12)
    thr, phr = np.radians(th), np.radians(ph)
    e_th = np.stack([np.cos(thr) * np.cos(phr), np.cos(thr) * np.sin(phr), -np.sin(thr)], 1)
    e_ph = np.stack([-np.sin(phr), np.cos(phr), 0 * phr], 1)
    readme = ((s[:, 1] * np.cos(phr) + s[:, 2] * np.sin(phr))[:, None] * e_th
              - (s[:, 3] * np.cos(phr) + s[:, 0] * np.sin(phr))[:, None] * e_ph)
    np.testing.assert_allclose(ae.amplitude_vectors(s, th, ph, [1, 0, 0]), readme, atol=1e-12)


def test_phase_origin_factor_matches_a_shifted_point_scatterer() -> None:
    """A point scatterer at s: far field about the origin = about s times exp(ik(a-n).s)."""
    k, s = 12.0, np.array([0.1, -0.05, 0.3])
    a = np.array([0.0, 0.0, -1.0])
    rng = np.random.default_rng(5)
    n = rng.normal(size=(20, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    about_origin = np.exp(1j * k * ((a - n) @ s))  # incident phase at s, outgoing path
    np.testing.assert_allclose(about_origin * ae.phase_origin_factor(n, s, k, a), 1.0)


# -- files -----------------------------------------------------------------------------------


def test_read_ampl_scatgrid_by_row_order_and_checks_order() -> None:
    path = ADDA_DATA / "d_janus_o0_0_0" / "ampl_scatgrid"
    th, ph = grid_angles()
    s = ae.read_ampl_scatgrid(path, th, ph)
    raw = np.loadtxt(path, skiprows=1)
    assert s.shape == (1476, 4)
    np.testing.assert_array_equal(s[:, 0], raw[:, 2] + 1j * raw[:, 3])
    np.testing.assert_array_equal(s[:, 3], raw[:, 8] + 1j * raw[:, 9])
    # theta inner / phi outer is the wrong order: detected from the printed angles
    with pytest.raises(ae.AddaError, match="not in the requested order"):
        ae.read_ampl_scatgrid(path, np.tile(np.linspace(0, 20, 41), 36),
                              np.repeat(np.arange(36) * 10.0, 41))
    with pytest.raises(ae.AddaError, match="1476 rows for 10"):
        ae.read_ampl_scatgrid(path, th[:10], ph[:10])


def test_read_ampl_scatgrid_rejects_mueller_and_missing(tmp_path) -> None:
    bad = tmp_path / "mueller_scatgrid"
    bad.write_text("theta phi s11 s12\n0 0 1 2\n")
    with pytest.raises(ae.AddaError, match="unexpected header"):
        ae.read_ampl_scatgrid(bad)
    with pytest.raises(ae.AddaError, match="wrote no ampl_scatgrid"):
        ae.read_ampl_scatgrid(tmp_path / "nothing")


def test_shape_file_round_trip_in_flipped_frame(tmp_path) -> None:
    model = JanusSphere(0.3, 0.06, 1.59, 2.7)
    lat = voxelize(model, 0.05, "binary")
    geom = ae.adda_geometry(lat)
    path = ae.write_geometry(tmp_path / "shape.dat", geom)
    ijk, dom = read_shape_file(path)
    np.testing.assert_array_equal(ijk, geom.ijk)
    np.testing.assert_array_equal(dom + 1, geom.domain)
    assert "Nmat=2" in path.read_text()
    # positions: ADDA particle frame = T (holofit particle frame), about the box centre
    ours = lat.positions + geom.centre_offset_um
    np.testing.assert_allclose(geom.positions_adda(), ours @ ae.T_LAB, atol=1e-12)
    # the particle centre: the core's centre of mass in holofit's frame is the origin
    core = lat.positions[np.argmax(lat.fractions, axis=1) == 0].mean(axis=0)
    np.testing.assert_allclose(core[:2], 0.0, atol=1e-12)
    single = ae.adda_geometry(voxelize(Spherocylinder(0.2, 0.4, 1.5), 0.05, "binary"))
    text = ae.write_geometry(tmp_path / "rod.dat", single).read_text()
    assert "Nmat" not in text and len(text.splitlines()[3].split()) == 3


def test_pairs_file_keeps_full_precision(tmp_path) -> None:
    th = np.array([0.0, 10.123456789012345, 179.5])
    ph = np.array([359.99999999, 33.333333333333336, 0.0])
    text = ae.write_pairs_file(tmp_path / "p.dat", th, ph).read_text().splitlines()
    assert text[:3] == ["global_type=pairs", "N=3", "pairs="]
    back = np.array([[float(v) for v in line.split()] for line in text[3:]])
    np.testing.assert_array_equal(back, np.column_stack([th, ph]))


def test_command_line_for_the_recorded_janus_run() -> None:
    model, orientation, _ = recorded_problem("d_janus_o0_0_0")
    optics = Optics(WAVELENGTH, N_MEDIUM)
    geom = ae.adda_geometry(voxelize(model, model.dipole_size_um))
    args = ae.adda_command(geom, optics, ae.adda_orientation_deg(orientation), "shape.dat",
                           "pairs.dat", "out", tolerance=1e-5, max_iterations=300)

    def value(flag: str, count: int = 1) -> list[str]:
        i = args.index(flag)
        return args[i + 1 : i + 1 + count]

    assert value("-shape", 2) == ["read", "shape.dat"]
    assert float(value("-size")[0]) == pytest.approx(0.96, abs=1e-12)  # as recorded
    assert float(value("-lambda")[0]) == pytest.approx(0.4962406015, abs=1e-10)
    m = [float(v) for v in value("-m", 4)]
    np.testing.assert_allclose(m, [1.195488722, 0.0, 2.030075188, 0.0], atol=1e-9)
    assert float(value("-eps")[0]) == pytest.approx(5.0)
    assert value("-maxiter") == ["300"]
    assert value("-scat_matr") == ["ampl"]
    assert value("-scat_grid_inp") == ["pairs.dat"] and value("-dir") == ["out"]
    assert "-store_scat_grid" in args


# -- recorded ADDA output vs the built-in engine on the same dipoles --------------------------


@pytest.fixture(scope="module")
def builtin_far_fields() -> dict:
    """Built-in F(n) (holofit lab) for each recorded case, x and y polarisation."""
    th, ph = grid_angles()
    n_lab = adda_dirs(th, ph) @ ae.T_LAB
    out = {}
    for name in CASES:
        model, orientation, _ = recorded_problem(name)
        engine = BuiltinDDA(tolerance=1e-8, polarizability="ldr")  # ADDA's prescription
        for pol in (0.0, np.pi / 2):
            wave = engine.solve(model, Optics(WAVELENGTH, N_MEDIUM, pol), orientation)
            out[name, pol] = wave.far_field_amplitude(n_lab)
    return out


@pytest.mark.parametrize("name", list(CASES))
def test_adapter_input_is_equivalent_to_the_recorded_run(name: str) -> None:
    """The flipped dipoles rotated by the adapter's -orient are the recorded dipoles rotated by
    the recorded -orient (same lab point set about the box centre)."""
    model, orientation, r_adda = recorded_problem(name)
    geom = ae.adda_geometry(voxelize(model, model.dipole_size_um))
    ours = geom.positions_adda() @ euler_zyz(*np.radians(ae.adda_orientation_deg(orientation))).T
    ijk, _ = read_shape_file(model.path)
    box = ijk.max(axis=0) - ijk.min(axis=0) + 1
    rec = ((ijk - ijk.min(axis=0)) - (box - 1) / 2) * model.dipole_size_um @ r_adda.T

    assert geom.n_dipoles == rec.shape[0] == CASES[name]["N_dipoles"]
    dist, _ = cKDTree(rec).query(ours)
    assert dist.max() < 1e-9 * model.dipole_size_um * 1e3


@pytest.mark.parametrize("name", list(CASES))
@pytest.mark.parametrize("pol", [0.0, np.pi / 2, 0.6])
def test_recorded_adda_amplitudes_match_builtin_engine(name: str, pol: float,
                                                        builtin_far_fields: dict) -> None:
    model, orientation, _ = recorded_problem(name)
    th, ph = grid_angles()
    n_lab = adda_dirs(th, ph) @ ae.T_LAB
    optics = Optics(WAVELENGTH, N_MEDIUM, pol)
    geom = ae.adda_geometry(voxelize(model, model.dipole_size_um))
    rot = euler_zyz(*orientation.as_tuple())
    # the recorded runs are in ADDA's lab T (x polarisation); for another polarisation the
    # conversion superposes ADDA's X and Y solutions, and so does the reference here
    f_adda = ae.far_field_from_ampl(recorded_ampl(name), th, ph, n_lab, optics, rot,
                                    geom.centre_offset_um, lab=ae.T_LAB)
    f_ref = (np.cos(pol) * builtin_far_fields[name, 0.0]
             + np.sin(pol) * builtin_far_fields[name, np.pi / 2])
    assert rel_err(f_adda, f_ref) < 1e-6


def test_janus_decides_the_frame_and_the_phase_origin(builtin_far_fields: dict) -> None:
    """Wrong frame (cap toward the source) or no phase-origin correction: clear mismatch."""
    name = "d_janus_o0_0_0"
    model, orientation, _ = recorded_problem(name)
    th, ph = grid_angles()
    n_lab = adda_dirs(th, ph) @ ae.T_LAB
    optics = Optics(WAVELENGTH, N_MEDIUM, 0.0)
    geom = ae.adda_geometry(voxelize(model, model.dipole_size_um))
    s = recorded_ampl(name)
    rot = euler_zyz(*orientation.as_tuple())
    f_ref = builtin_far_fields[name, 0.0]
    good = rel_err(ae.far_field_from_ampl(s, th, ph, n_lab, optics, rot, geom.centre_offset_um),
                   f_ref)
    no_shift = rel_err(ae.far_field_from_ampl(s, th, ph, n_lab, optics, rot, np.zeros(3)), f_ref)
    assert good < 1e-6
    assert no_shift > 1e-3 and no_shift > 1000 * good
    # a mirrored frame would have taken the recorded run for the cap toward the source
    # (theta = 0): that particle scatters measurably differently
    cap_up = BuiltinDDA(tolerance=1e-6).solve(model, optics, Orientation(0.0, 0.0, 0.0))
    f_good = ae.far_field_from_ampl(s, th, ph, n_lab, optics, rot, geom.centre_offset_um)
    assert rel_err(f_good, cap_up.far_field_amplitude(n_lab)) > 1e-2
    assert orientation.theta == pytest.approx(np.pi)  # recorded cap along ADDA +z = our theta=pi
