"""The cluster engine (superposition T-matrix) against independent references: the translation
theorem against direct evaluation of the waves, Lorenz-Mie for one sphere anywhere, the sum of
two Mie fields for spheres far apart, the optical theorem, reciprocity, its own truncation
rule, and an independent code (treams, a test-only dependency)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.special import spherical_jn

from holofit.config import ConfigError, load_particle
from holofit.engines.select import select_engine
from holofit.fit.problem import FrameProblem
from holofit.optics import Optics
from holofit.particles import Cluster, CoatedSphere, Dimer, Sphere, Spherocylinder
from holofit.scattering.cluster import (
    ClusterEngine,
    ClusterWave,
    SphereSumWave,
    solve_cluster,
)
from holofit.scattering.legendre import legendre_tables
from holofit.scattering.mie import MieWave, cross_sections
from holofit.scattering.multipole import MultipoleExpansion, _sum_points
from holofit.scattering.theory import Orientation
from holofit.scattering.translation import translation_matrix
from holofit.scattering.vsw import n_terms, unpack

OPTICS = Optics(0.66, 1.33, 0.3)
K = OPTICS.k


def regular_field(vec: np.ndarray, order: int, pts: np.ndarray, k: float) -> np.ndarray:
    """Field of regular-wave coefficients at points (the outgoing series with j_n in place of
    h_n, summed by the multipole module's compiled kernel)."""
    p, q = unpack(vec, order)
    pts = np.atleast_2d(pts)
    r = np.linalg.norm(pts, axis=1)
    th = np.arccos(np.clip(pts[:, 2] / r, -1, 1))
    ph = np.arctan2(pts[:, 1], pts[:, 0])
    x = k * r
    n = np.arange(order + 1)
    j = spherical_jn(n[None], x[:, None])
    jp = spherical_jn(n[None], x[:, None], derivative=True)
    h = j.astype(complex)
    dx = (j / x[:, None] + jp).astype(complex)
    hk = (n * (n + 1) * j / x[:, None]).astype(complex)
    pb, dp, mp = legendre_tables(np.ascontiguousarray(np.cos(th)), order)
    sph = np.empty((pts.shape[0], 3), complex)
    _sum_points(np.ascontiguousarray(p), np.ascontiguousarray(q), h, dx, hk, pb, dp, mp,
                np.ascontiguousarray(ph), sph)
    er, et, ep = sph.T
    st, ct, sp, cp = np.sin(th), np.cos(th), np.sin(ph), np.cos(ph)
    return np.stack([er * st * cp + et * ct * cp - ep * sp, er * st * sp + et * ct * sp + ep * cp,
                     er * ct - et * st], 1)


def outgoing_field(vec: np.ndarray, order: int, pts: np.ndarray, k: float) -> np.ndarray:
    p, q = unpack(vec, order)
    return MultipoleExpansion(k, p, q, 0.0).field_at(pts)


def _rel(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.abs(a - b).max() / np.abs(b).max())


# -- the translation theorem -----------------------------------------------------------------


@pytest.mark.parametrize("d", [(0.0, 0.0, 0.9), (0.0, 0.0, -0.7), (0.3, -0.5, 0.6)])
def test_translation_reproduces_the_waves(d: tuple[float, float, float]) -> None:
    rng = np.random.default_rng(2)
    src_order = 6
    c = rng.normal(size=n_terms(src_order)) + 1j * rng.normal(size=n_terms(src_order))
    d = np.asarray(d)
    dist = np.linalg.norm(d)
    r = rng.normal(size=(6, 3))
    r *= 0.25 * dist / np.linalg.norm(r, axis=1)[:, None]
    # regular -> regular and outgoing -> regular inside |r'| < |d|
    reg = translation_matrix(d, K, 26, src_order, "regular")
    assert _rel(regular_field(reg @ c, 26, r, K), regular_field(c, src_order, r + d, K)) < 1e-11
    out = translation_matrix(d, K, 30, src_order, "outgoing")
    assert _rel(regular_field(out @ c, 30, r, K), outgoing_field(c, src_order, r + d, K)) < 1e-11
    # outgoing -> outgoing outside |r'| > |d|
    far = r * 12.0
    o2o = translation_matrix(d, K, 40, src_order, "regular")
    assert _rel(outgoing_field(o2o @ c, 40, far, K), outgoing_field(c, src_order, far + d, K)) \
        < 1e-9


# -- one sphere ------------------------------------------------------------------------------


@pytest.mark.parametrize("offset", [(0.0, 0.0, 0.0), (0.1, -0.2, 0.3)])
def test_one_sphere_anywhere_is_lorenz_mie(offset: tuple[float, float, float]) -> None:
    sphere = Sphere(0.5, 1.59 + 0.002j)
    off = np.asarray(offset)
    sol = solve_cluster([off], [0.5], [sphere.index], OPTICS)
    wave = ClusterWave(sphere, OPTICS, Orientation(0.3, 0.7, 0.2), sol)
    mie = MieWave(sphere, OPTICS)
    c = wave.rotation @ off
    x, y = np.meshgrid(np.linspace(-5, 5, 31), np.linspace(-4, 4, 29))
    pos = np.array([0.2, 0.1, 8.0])
    ex, ey = wave.field_on_pixels(pos, x.ravel(), y.ravel())
    mx, my = mie.field_on_pixels(pos + c, x.ravel(), y.ravel())
    assert _rel(np.stack([ex, ey]), np.stack([mx, my])) < 1e-9
    near = np.array([[0.9, 0.3, 0.2], [-0.4, 1.1, 0.5], [0.2, 0.2, -0.9]])  # SphereSumWave
    ref = mie.field_at(near - c) * np.exp(-1j * K * c[2])
    assert _rel(wave.field_at(near), ref) < 1e-10


def test_two_spheres_far_apart_tend_to_the_sum_of_two_mie_fields() -> None:
    """The multiple-scattering part decays as 1/(k d): halving it when d doubles."""
    pts = np.array([[1.5, 0.7, 0.4], [-1.0, 1.3, -0.8], [0.3, -1.2, 1.1]])
    errs = []
    for sep in (3.0, 6.0):
        cl = Cluster((0.3, 0.35), (1.59, 1.45 + 0.01j), ((0, 0, -sep / 2), (0, 0, sep / 2)))
        wave = ClusterEngine().solve(cl, OPTICS, Orientation(0.4, 1.1, 0.3))
        ref = 0
        for rad, n, p in zip(cl.radii_um, cl.indices, cl.positions_um, strict=True):
            c = wave.rotation @ np.asarray(p)
            ref = ref + MieWave(Sphere(rad, n), OPTICS).field_at(pts - c) \
                * np.exp(-1j * K * c[2])
        errs.append(_rel(wave.field_at(pts), ref))
    assert errs[0] < 0.05
    assert 1.6 < errs[0] / errs[1] < 2.5


# -- conservation laws -----------------------------------------------------------------------


def _sphere_quadrature(n: int = 64) -> tuple[np.ndarray, np.ndarray]:
    mu, w = np.polynomial.legendre.leggauss(n)
    phi = 2 * np.pi * np.arange(2 * n) / (2 * n)
    st = np.sqrt(1 - mu**2)
    dirs = np.stack([np.outer(st, np.cos(phi)), np.outer(st, np.sin(phi)),
                     np.repeat(mu[:, None], phi.size, 1)], -1).reshape(-1, 3)
    return dirs, np.repeat(w, phi.size) * (2 * np.pi / phi.size)


def _absorption(sol, wave: ClusterWave) -> float:
    """Sum over the spheres of the inward flux of the field each one feels plus its own:
    ``-(1/k^2) sum n(n+1) (|p|^2 + Re(conj(e) p))`` with ``e = T_i^-1 p`` (Mie)."""
    from holofit.scattering.cluster import sphere_tmatrix
    from holofit.scattering.translation import wigner_matrix

    psi, theta, phi = wave.orientation.as_tuple()
    tm = sol.tmatrix
    a = wigner_matrix(tm.order, psi, theta, phi).conj().T @ tm.incident_coefficients(
        OPTICS.polarization)
    total = 0.0
    model = wave.model
    for p, L, rad, n_abs in zip(sol.sphere_coefficients(a), sol.orders, sol.radii_um,
                                model.indices, strict=True):
        t = sphere_tmatrix(n_abs / OPTICS.n_medium, K * rad, L)
        e = p / t
        from holofit.scattering.vsw import term_indices

        _, nn, _ = term_indices(L)
        total += -np.sum(nn * (nn + 1) * (np.abs(p) ** 2 + (np.conj(e) * p).real)) / K**2
    return float(total)


def test_optical_theorem_absorbing_dimer() -> None:
    cl = Cluster((0.4, 0.3), (1.59 + 0.05j, 1.8 + 0.1j), ((0, 0, -0.4), (0.05, 0.2, 0.3)))
    sol = ClusterEngine().solution(cl, OPTICS)
    wave = ClusterWave(cl, OPTICS, Orientation(0.5, 0.9, 1.3), sol)
    fwd = wave.far_field_amplitude(np.array([[0.0, 0.0, -1.0]]))[0]
    c_ext = 4 * np.pi / K**2 * float(np.real(fwd @ OPTICS.polarization))
    dirs, w = _sphere_quadrature()
    f = wave.far_field_amplitude(dirs)
    c_sca = float(np.sum(w * np.sum(np.abs(f) ** 2, axis=1))) / K**2
    c_abs = _absorption(sol, wave)
    assert c_abs > 0.05 * c_ext
    assert abs(c_ext - (c_sca + c_abs)) < 1e-9 * c_ext


def test_absorption_formula_is_mie_for_one_sphere() -> None:
    sphere = Sphere(0.4, 1.59 + 0.05j)
    cl = Cluster((0.4,), (sphere.index,), ((0.1, 0.0, 0.2),))
    sol = ClusterEngine().solution(cl, OPTICS)
    wave = ClusterWave(cl, OPTICS, Orientation(), sol)
    ref = cross_sections(sphere.index / OPTICS.n_medium, 0.4, K)
    assert _absorption(sol, wave) == pytest.approx(ref.absorption_um2, rel=1e-10)


def _amplitude(theory: ClusterEngine, model: Cluster, inc: np.ndarray, e_inc: np.ndarray,
               out: np.ndarray) -> np.ndarray:
    """Far-field amplitude (particle frame) in direction ``out`` for a plane wave along
    ``inc`` polarised ``e_inc`` (particle frame): the particle is turned so that ``inc``
    points along lab -z."""
    from holofit.conventions import euler_zyz_from_matrix

    z = -inc / np.linalg.norm(inc)
    x = e_inc / np.linalg.norm(e_inc)
    rot = np.stack([x, np.cross(z, x), z])  # rows: lab axes in the particle frame
    psi, theta, phi = (float(v) for v in euler_zyz_from_matrix(rot))
    optics = Optics(OPTICS.wavelength_um, OPTICS.n_medium, 0.0)
    wave = theory.solve(model, optics, Orientation(psi, theta, phi))
    assert np.allclose(wave.rotation @ inc, [0, 0, -1])
    f_lab = wave.far_field_amplitude((wave.rotation @ out)[None])[0]
    return wave.rotation.T @ f_lab


def test_reciprocity() -> None:
    """``e_s . F(v; u, e_i) = e_i . F(-u; -v, e_s)`` for any directions and polarisations."""
    cl = Cluster((0.25, 0.2, 0.22), (1.59, 1.8 + 0.05j, 1.45),
                 ((0, 0, -0.28), (0.12, 0.3, 0.2), (-0.38, -0.12, 0.25)))
    th = ClusterEngine()
    rng = np.random.default_rng(5)
    for _ in range(3):
        u, v = (x / np.linalg.norm(x) for x in rng.normal(size=(2, 3)))
        e_i = np.cross(u, rng.normal(size=3))
        e_s = np.cross(v, rng.normal(size=3))
        e_i /= np.linalg.norm(e_i)
        e_s /= np.linalg.norm(e_s)
        forward = e_s @ _amplitude(th, cl, u, e_i, v)
        backward = e_i @ _amplitude(th, cl, -v, e_s, -u)
        assert abs(forward - backward) < 1e-9 * abs(forward)


# -- truncation and the independent code -----------------------------------------------------


def test_truncation_rule_is_converged_for_touching_spheres() -> None:
    model = Dimer(0.53, 0.53, 0.0, 1.59, 1.59)
    th = ClusterEngine()
    base = th.solution(model, OPTICS)
    from holofit.scattering.cluster import cluster_spheres

    pos, radii, idx = cluster_spheres(model)
    more = solve_cluster(pos, radii, idx, OPTICS, sphere_margin=6, order=base.tmatrix.order + 4)
    x, y = np.meshgrid(np.linspace(-6, 6, 25), np.linspace(-6, 6, 25))
    o = Orientation(0.3, 1.0, 0.5)
    a = ClusterWave(model, OPTICS, o, base).field_on_pixels((0, 0, 10.0), x.ravel(), y.ravel())
    b = ClusterWave(model, OPTICS, o, more).field_on_pixels((0, 0, 10.0), x.ravel(), y.ravel())
    assert _rel(np.stack(a), np.stack(b)) < 2e-8  # measured 9.4e-9
    rot = ClusterWave(model, OPTICS, o, base).rotation
    near = np.array([[0.0, 0.7, 0.0], [0.6, 0.0, 0.5]]) @ rot.T  # beside the contact point
    assert _rel(SphereSumWave(base, OPTICS, o).field_at(near),
                SphereSumWave(more, OPTICS, o).field_at(near)) < 2e-6  # measured 6.9e-7


def _treams_field(model: Cluster, pts: np.ndarray, lmax: int) -> np.ndarray:
    treams = pytest.importorskip("treams")
    import warnings

    warnings.filterwarnings("ignore", category=DeprecationWarning, module="treams")
    optics = Optics(OPTICS.wavelength_um, OPTICS.n_medium, 0.0)
    k0 = 2 * np.pi / optics.wavelength_um
    med = treams.Material(optics.n_medium**2)
    spheres = [treams.TMatrix.sphere(lmax, k0, r, [treams.Material(complex(n) ** 2), med])
               for r, n in zip(model.radii_um, model.indices, strict=True)]
    tm = treams.TMatrix.cluster(spheres, np.asarray(model.positions_um)).interaction.solve()
    inc = treams.plane_wave([0, 0, -optics.k], [1, 0, 0], k0=k0, material=med)
    return np.asarray((tm @ inc.expand(tm.basis)).efield(pts))


@pytest.mark.parametrize("model", [
    Cluster((0.2, 0.15), (1.59, 1.59), ((0, 0, -0.2), (0, 0, 0.15))),
    pytest.param(Cluster((0.53, 0.53), (1.59, 1.59), ((0, 0, -0.53), (0, 0, 0.53))),
                 marks=pytest.mark.slow),
    pytest.param(Cluster((0.25, 0.2, 0.22), (1.59, 1.8 + 0.05j, 1.45),
                         ((0, 0, -0.28), (0.12, 0.3, 0.2), (-0.38, -0.12, 0.25))),
                 marks=pytest.mark.slow),
], ids=["touching small dimer", "touching dimer 0.53", "trimer"])
def test_against_treams(model: Cluster) -> None:
    """An independent T-matrix code (treams: its own Mie coefficients, translation
    coefficients and field evaluation), same sphere orders: the fields agree within 1e-6."""
    optics = Optics(OPTICS.wavelength_um, OPTICS.n_medium, 0.0)
    sol = ClusterEngine().solution(model, optics)
    wave = ClusterWave(model, optics, Orientation(), sol)
    rng = np.random.default_rng(3)
    pts = rng.normal(size=(4, 3))
    pts *= (np.linspace(1.5, 4.0, 4) * model.bounding_radius_um
            / np.linalg.norm(pts, axis=1))[:, None]
    ref = _treams_field(model, pts, max(sol.orders))
    assert _rel(wave.field_at(pts), ref) < 1e-6


# -- engine choice and configs ---------------------------------------------------------------


def test_auto_picks_the_exact_engines() -> None:
    from holofit.dda.settings import DDASettings

    dimer = Dimer(0.5, 0.5, 0.0, 1.59, 1.59)
    assert select_engine(dimer).name == "cluster"
    assert select_engine(dimer, DDASettings()).name == "cluster"
    assert select_engine(dimer, DDASettings(), engine="builtin").name == "builtin"
    coated = CoatedSphere(0.44, 0.047, 1.58, 2.74)
    assert select_engine(coated).name == "coated_sphere"
    assert select_engine(Sphere(0.5, 1.5), DDASettings()).name == "builtin"
    with pytest.raises(ValueError, match="cluster engine handles"):
        select_engine(Spherocylinder(0.3, 0.8, 1.5), engine="cluster")


def test_cluster_config_errors_name_the_file(tmp_path) -> None:
    path = tmp_path / "c.toml"
    path.write_text('[particle]\nmodel = "cluster"\nradii_um = [0.5, 0.5]\n'
                    'indices = [1.59, 1.59]\npositions_um = [[0, 0, 0], [0, 0, 0.9]]\n')
    with pytest.raises(ConfigError, match=r"c\.toml.*overlap"):
        load_particle(path)
    path.write_text('[particle]\nmodel = "cluster"\nradii_um = [0.5, 0.5]\n'
                    'indices = [1.59]\npositions_um = [[0, 0, 0], [0, 0, 1.0]]\n')
    with pytest.raises(ConfigError, match=r"c\.toml.*one of each"):
        load_particle(path)
    path.write_text('[particle]\nmodel = "cluster"\nradii_um = [500, 0.5]\n'
                    'indices = [1.59, 1.5]\npositions_um = [[0, 0, 0], [0, 0, 1.0]]\n')
    with pytest.raises(ConfigError, match=r"radii_um\[0\].*nanometres"):
        load_particle(path)


def test_example_cluster_config_loads_and_solves() -> None:
    from pathlib import Path

    cfg = load_particle(Path(__file__).resolve().parents[1] / "configs" / "particles"
                        / "cluster_trimer.toml")
    assert isinstance(cfg.model, Cluster) and len(cfg.model.radii_um) == 3
    assert isinstance(cfg.theory(), ClusterEngine)
    assert cfg.theory("builtin").name == "builtin"


# -- through the objective lens, and the coated-sphere engine --------------------------------


def test_lens_image_of_one_sphere_cluster_is_the_mie_image() -> None:
    """The lens model images the cluster's multipole expansion (its ExpansionPupil) and a
    sphere from its S1, S2 (SpherePupil): two paths, one field."""
    from holofit.conventions import DetectorGrid
    from holofit.scattering.lens import lens_field_on_detector

    optics = Optics(0.66, 1.33, 0.3, numerical_aperture=1.2)
    sphere = Sphere(0.5, 1.59)
    grid = DetectorGrid((40, 40), 0.15)
    pos = (3.0, 3.1, 9.0)
    cl = ClusterEngine().solve(Cluster((0.5,), (1.59,), ((0.0, 0.0, 0.0),)), optics,
                               Orientation(0.3, 0.8, 0.1))
    a = np.stack(lens_field_on_detector(cl, pos, grid))
    b = np.stack(lens_field_on_detector(MieWave(sphere, optics), pos, grid))
    assert _rel(a, b) < 1e-6


def test_coated_sphere_engine() -> None:
    """``coated_sphere`` solves the model with coated-sphere Lorenz-Mie; with equal indices it
    is the homogeneous sphere, directly and through the lens (its expansion)."""
    from holofit.conventions import DetectorGrid
    from holofit.scattering.coated_mie import CoatedSphereWave
    from holofit.scattering.lens import lens_field_on_detector

    optics = Optics(0.66, 1.33, 0.3, numerical_aperture=1.2)
    model = CoatedSphere(0.443, 0.047, 1.581, 2.74)
    wave = select_engine(model).solve(model, optics)
    ref = CoatedSphereWave(0.443, 0.49, 1.581, 2.74, optics)
    pts = np.array([[1.0, 0.2, 0.5], [0.1, -2.0, 3.0]])
    assert _rel(wave.field_at(pts), ref.field_at(pts)) < 1e-14
    same = CoatedSphere(0.3, 0.2, 1.59, 1.59)
    coated = select_engine(same).solve(same, optics)
    mie = MieWave(Sphere(0.5, 1.59), optics)
    grid = DetectorGrid((30, 30), 0.15)
    pos = (2.0, 2.3, 8.0)
    assert _rel(np.stack(coated.field_on_detector(pos, grid)),
                np.stack(mie.field_on_detector(pos, grid))) < 1e-10
    assert _rel(np.stack(lens_field_on_detector(coated, pos, grid)),
                np.stack(lens_field_on_detector(mie, pos, grid))) < 1e-6
    with pytest.raises(ValueError, match="coated_sphere engine handles coated spheres"):
        select_engine(Sphere(0.5, 1.5), engine="coated_sphere")


@pytest.mark.parametrize("model", [
    CoatedSphere(0.3, 0.1, 1.59, 1.45),
    Cluster((0.25, 0.2), (1.59, 1.45), ((0.0, 0.0, -0.25), (0.0, 0.25, 0.2))),
], ids=["coated sphere", "cluster"])
def test_builtin_dda_of_the_new_models_is_close_to_exact(model) -> None:
    """``--engine builtin`` discretises both new models; at the default rule its camera field
    is within a few 1e-3 of the exact engines'."""
    from holofit.conventions import DetectorGrid

    optics = Optics(0.66, 1.33, 0.0)
    o = Orientation(0.3, 0.6, 0.2)
    exact = select_engine(model).solve(model, optics, o)
    dda = select_engine(model, engine="builtin").solve(model, optics, o)
    grid = DetectorGrid((40, 40), 0.2)
    pos = (4.0, 4.0, 10.0)
    assert _rel(np.stack(dda.field_on_detector(pos, grid)),
                np.stack(exact.field_on_detector(pos, grid))) < 1e-2


def test_frame_fit_with_the_cluster_engine_recovers_the_truth() -> None:
    """A noisy dimer hologram made by the cluster engine, fitted by it (library starts, sizes
    fixed): position within 5 nm and axis within 1 degree of the truth."""
    import math

    from holofit.camera import Camera
    from holofit.conventions import DetectorGrid
    from holofit.fit.frame import fit_frame
    from holofit.hologram import calc_hologram
    from holofit.library.polar import polar_grid, sample_crop
    from holofit.library.search import OrientationLibrary, pick_candidates, tilt_grid

    optics = Optics(0.66, 1.33, 0.0)
    model = Dimer(0.4, 0.45, 0.0, 1.59, 1.59)
    th = select_engine(model)
    truth = Orientation(0.7, 1.1, 0.0)
    px = 0.12
    grid = DetectorGrid((90, 90), px, (10, 20))
    pos = ((20 + 45.3) * px, (10 + 44.6) * px, 10.0)
    holo = calc_hologram(th.solve(model, optics, truth), pos, grid, 0.9)
    crop = Camera(background_counts=120.0).expose(holo, np.random.default_rng(0)) / 120.0
    start = (pos[0] + 0.03, pos[1] - 0.02, pos[2] + 0.2)
    lib = OrientationLibrary(th, model, optics, tilt_grid(model, math.radians(10)))
    pg = polar_grid(start[:2], 44 * px, px, 128)
    d, w = sample_crop(crop, grid.corner, px, pg)
    cands = pick_candidates(lib.scores(pg, d, w, start, 0.8), lib.tilts, pg.phi, model, 4,
                            math.radians(20))
    free = ("x_um", "y_um", "z_um", "orientation", "alpha")
    res = fit_frame(FrameProblem(crop, grid.corner, px, th, model, optics, free), start, 0.8,
                    cands)
    assert res.status == "ok"
    err = math.dist([res.values[k] for k in ("x_um", "y_um", "z_um")], pos)
    assert err < 0.005
    ut = np.array(
        [
            math.sin(truth.theta) * math.cos(truth.psi),
            math.sin(truth.theta) * math.sin(truth.psi),
            math.cos(truth.theta),
        ]
    )
    u = np.array([res.values[k] for k in ("ux", "uy", "uz")])
    assert math.degrees(math.acos(min(1.0, float(u @ ut) / np.linalg.norm(u)))) < 1.0


def test_sphere_sum_far_field_form_is_the_expansion_far_field() -> None:
    """The spheres' own far fields, phased by their positions, equal the cluster expansion's
    asymptotic field (two independent evaluations of ``far_field=True``)."""
    cl = Cluster((0.3, 0.25), (1.59, 1.7 + 0.02j), ((0.0, 0.0, -0.3), (0.1, 0.2, 0.25)))
    sol = ClusterEngine().solution(cl, OPTICS)
    o = Orientation(0.4, 0.8, 0.2)
    pts = np.array([[3.0, -2.0, 40.0], [-5.0, 1.0, -30.0], [20.0, 10.0, 5.0]])
    a = SphereSumWave(sol, OPTICS, o).field_at(pts, far_field=True)
    b = ClusterWave(cl, OPTICS, o, sol).field_at(pts, far_field=True)
    assert _rel(a, b) < 1e-9
