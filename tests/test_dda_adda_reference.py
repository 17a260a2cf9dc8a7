"""The built-in DDA against ADDA's own output on the same dipoles (reference/adda).

Run in ADDA's frame (light along +z), with ADDA's prescription (LDR with the S term, point
dipoles, binary voxels from the saved .geom files), both polarisations, the amplitude matrix in
ADDA's basis. The Janus case is asymmetric along z, so it only agrees if our frame is not
mirrored; its amplitudes are referred from the core centre back to ADDA's box-centre origin.
"""

import json

import numpy as np
import pytest

from holofit.conventions import euler_zyz
from holofit.dda.adda.frames import adda_amplitude_matrix
from holofit.dda.dipoles import DipoleSystem, incident_field
from holofit.dda.farfield import far_field
from holofit.dda.polarizability import polarizability
from holofit.dda.voxelize import voxelize
from holofit.io.shapefile import read_shape_file
from holofit.particles import VoxelShape
from tests.conftest import DATA

REF = DATA / "adda"
CASES = json.loads((REF / "cases.json").read_text())
GEOM = {
    "a_sphere_r0.45": "a_sphere_r0.45/sphere.geom",
    "c_capsule_o0_0_0": "c_capsule_o0_0_0/capsule.geom",
    "c_capsule_o30_60_0": "c_capsule_o0_0_0/capsule.geom",
    "d_janus_o0_0_0": "d_janus_o0_0_0/janus_d0.024.geom",
}


def _adda_case(name, tol, geom=None, centre_sign=1.0):
    case = CASES[name]
    k = 2 * np.pi / case["lambda_adda_um"]
    centre = tuple(centre_sign * c for c in case.get("sphere_centre_particle_frame_um", (0, 0, 0)))
    model = VoxelShape(str(geom or REF / GEOM[name]), case["dipole_size_um"],
                       tuple(float(m) for m in case["m_rel"]), centre)
    lat = voxelize(model, case["dipole_size_um"])
    assert lat.n_dipoles == case["N_dipoles"] and lat.shape == tuple(case["box"])
    rot = euler_zyz(*np.radians(case["orient_deg"]))
    system = DipoleSystem(lat, k, 1.0, "ldr")  # ADDA's problem is scaled into the medium
    a_p = rot.T @ [0.0, 0.0, 1.0]
    pols = (np.array([1.0, 0, 0]), np.array([0, 1.0, 0]))
    sols = [system.solve(a_p, rot.T @ e, tol=tol) for e in pols]
    theta = np.radians(np.repeat(np.linspace(0, 20, 41), 36))  # row = i_theta * 36 + i_phi
    phi = np.radians(np.tile(np.arange(36) * 10.0, 41))
    n_lab = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], 1)
    f = [far_field(lat, s.P, k, n_lab @ rot) @ rot.T for s in sols]
    s_mat = adda_amplitude_matrix(f[0], f[1], theta, phi)
    # refer to ADDA's origin (box centre): the core centre sits at `centre` from it
    s_lab = rot @ np.array(case.get("sphere_centre_particle_frame_um", (0.0, 0.0, 0.0)))
    s_mat *= np.exp(1j * k * ((np.array([0, 0, 1.0]) - n_lab) @ s_lab))[:, None]
    ref = np.loadtxt(REF / name / "ampl_scatgrid", skiprows=1)
    s_ref = ref[:, 2::2] + 1j * ref[:, 3::2]
    cext = [
        4 * np.pi * k * np.sum(np.imag(np.sum(
            s.P * np.conj(incident_field(lat.positions, k, a_p, rot.T @ e)), axis=1)))
        for s, e in zip(sols, pols, strict=True)
    ]
    return s_mat, s_ref, cext, case, sols


@pytest.mark.parametrize("name", list(CASES))
def test_amplitude_matrix_matches_adda(name):
    s_mat, s_ref, cext, case, _ = _adda_case(name, tol=1e-7)
    err = np.max(np.abs(s_mat - s_ref)) / np.max(np.abs(s_ref))
    assert err <= 1e-4, err
    assert err <= 1e-6  # same dipoles, same prescription, tight tolerance: far better than 1e-4
    assert cext[0] == pytest.approx(case["Cext_X_um2"], rel=1e-6)
    assert cext[1] == pytest.approx(case["Cext_Y_um2"], rel=1e-6)


def test_janus_mirrored_frame_would_fail(tmp_path):
    """A z-mirrored particle frame puts the cap on the wrong side: the agreement is lost."""
    ijk, domain = read_shape_file(REF / GEOM["d_janus_o0_0_0"])
    ijk[:, 2] = -ijk[:, 2]
    mirrored = tmp_path / "mirrored.geom"
    mirrored.write_text("Nmat=2\n" + "\n".join(
        f"{i} {j} {k} {d + 1}" for (i, j, k), d in zip(ijk, domain, strict=True)) + "\n")
    s_mat, s_ref, *_ = _adda_case("d_janus_o0_0_0", tol=1e-6, geom=mirrored, centre_sign=-1)
    assert np.max(np.abs(s_mat - s_ref)) / np.max(np.abs(s_ref)) > 1e-2


def test_polarizability_matches_adda_couple_constant():
    # case a log: CoupleConstant = 1.211455317e-06 + 1.986037434e-09i um^3 (not rotated: S = 0)
    case = CASES["a_sphere_r0.45"]
    k = 2 * np.pi / case["lambda_adda_um"]
    alpha = polarizability(np.array([case["m_rel"][0] ** 2]), case["dipole_size_um"], k, "ldr")
    assert alpha[0].real == pytest.approx(1.211455317e-06, rel=1e-9)
    assert alpha[0].imag == pytest.approx(1.986037434e-09, rel=1e-8)


def test_default_tolerance_iterations_like_adda():
    """At ADDA's default tolerance our QMR needs about as many iterations as ADDA's."""
    *_, sols = _adda_case("c_capsule_o0_0_0", tol=1e-5)
    assert sols[0].iterations <= CASES["c_capsule_o0_0_0"]["iterations_eps1e-5"]["X"] + 2
