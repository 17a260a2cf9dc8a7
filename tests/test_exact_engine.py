"""The ``exact`` engine: registry entry and ``auto``'s choice, cache, waves, provenance, files,
and the fixed discretisation of a fit."""

from __future__ import annotations

import numpy as np
import pytest

from holofit.dda.settings import DDASettings
from holofit.dda.tmatrix_io import load_tmatrix, save_tmatrix
from holofit.engines.registry import ENGINE_NAMES, EXACT_ENGINES, get_engine
from holofit.engines.select import select_engine
from holofit.optics import Optics
from holofit.particles import (
    CoatedSphere,
    Cylinder,
    Dimer,
    Ellipsoid,
    JanusSphere,
    Sphere,
    Spherocylinder,
    Spheroid,
)
from holofit.scattering.axisym import (
    AxisymmetricTMatrix,
    TaperedJanusSphere,
    build_exact_tmatrix,
    supports,
)
from holofit.scattering.axisym.profiles import CapProfile
from holofit.scattering.multipole import NEAR_ZONE
from holofit.scattering.theory import Orientation
from holofit.scattering.tmatrix_wave import TMatrixWave

OPTICS = Optics(0.660, 1.33)
ROD = Spherocylinder(0.501, 1.079, 1.495)


def test_auto_picks_the_exact_engine_for_bodies_of_revolution() -> None:
    assert "exact" in ENGINE_NAMES and "exact" in EXACT_ENGINES
    assert isinstance(get_engine("exact"), AxisymmetricTMatrix)
    # auto: the exact T-matrix for a rod, a spheroid, a cylinder and a Janus sphere, with or
    # without DDA settings; the series for spheres and coated spheres; the DDA otherwise
    for model in (ROD, Spheroid(0.5, 1.0, 1.5), Cylinder(0.5, 1.0, 1.5),
                  JanusSphere(0.443, 0.047, 1.581, 2.74),
                  TaperedJanusSphere(0.443, 0.047, 1.581, 2.74)):
        assert select_engine(model).name == "exact", model.kind
        assert select_engine(model, DDASettings()).name == "exact", model.kind
        assert select_engine(model, engine="builtin").name == "builtin" or isinstance(
            model, TaperedJanusSphere)
    assert select_engine(Sphere(0.5, 1.59)).name == "mie"
    assert select_engine(Sphere(0.5, 1.59), DDASettings()).name == "builtin"
    assert select_engine(CoatedSphere(0.4, 0.05, 1.59, 2.7)).name == "coated_sphere"
    assert select_engine(Ellipsoid(0.3, 0.4, 0.5, 1.5)).name == "builtin"


def test_auto_gives_a_voxel_shape_the_dda(tmp_path) -> None:
    """A voxel file (an arbitrary shape: no exact engine handles it) gets the built-in DDA,
    with or without a ``[dda]`` table; asking for the exact engine says why not."""
    from holofit.config import load_particle
    from holofit.particles import VoxelShape

    geom = tmp_path / "l.geom"
    geom.write_text("0 0 0\n1 0 0\n2 0 0\n0 1 0\n")  # an L of four dipoles
    shape = VoxelShape(str(geom), 0.05, (1.5,))
    assert select_engine(shape).name == "builtin"
    assert select_engine(shape, DDASettings()).name == "builtin"
    with pytest.raises(ValueError, match="exact engine handles"):
        select_engine(shape, engine="exact")
    (tmp_path / "l.toml").write_text(
        f'[particle]\nmodel = "voxels"\npath = "{geom}"\ndipole_size_um = 0.05\n'
        "indices = [1.5]\n")
    assert load_particle(tmp_path / "l.toml").theory().name == "builtin"
    # the DDA settings' engine = "adda" still picks ADDA (here without a binary: it says so)
    with pytest.raises(Exception, match="ADDA"):
        select_engine(ROD, DDASettings(engine="adda"))


def test_a_config_that_names_its_dda_engine_gets_it_under_auto(tmp_path) -> None:
    from holofit.config import load_particle

    body = "[particle]\nmodel = \"spherocylinder\"\na_um = 0.3\nb_um = 0.7\nindex = 1.5\n"
    (tmp_path / "plain.toml").write_text(body + "[dda]\ndipole_size_um = 0.1\n")
    (tmp_path / "named.toml").write_text(body + "[dda]\nengine = \"builtin\"\n")
    assert load_particle(tmp_path / "plain.toml").theory().name == "exact"
    named = load_particle(tmp_path / "named.toml")
    assert named.theory().name == "builtin" and named.theory("auto").name == "builtin"
    assert named.theory("exact").name == "exact"
    assert load_particle("rod_paper").theory().name == "exact"
    assert load_particle("janus_paper").theory().name == "exact"
    assert load_particle("rod_paper").theory("builtin").name == "builtin"


def test_supports_bodies_of_revolution_only() -> None:
    assert supports(ROD) and supports(Spheroid(0.5, 0.8, 1.5))
    assert supports(JanusSphere(0.443, 0.047, 1.581, 2.74))
    assert not supports(Ellipsoid(0.3, 0.4, 0.5, 1.5))
    assert not supports(Dimer(0.3, 0.3, 0.0, 1.5, 1.5))
    with pytest.raises(TypeError):
        AxisymmetricTMatrix().solve(Dimer(0.3, 0.3, 0.0, 1.5, 1.5), OPTICS)


def test_engine_builds_once_and_serves_every_orientation() -> None:
    engine = AxisymmetricTMatrix()
    w1 = engine.solve(ROD, OPTICS, Orientation(0.3, 0.7, 0.0))
    w2 = engine.solve(ROD, OPTICS, Orientation(1.1, 0.2, 0.5))
    assert engine.builds == 1
    assert isinstance(w1, TMatrixWave) and isinstance(w2, TMatrixWave)
    # a spin about the rod's own axis changes nothing
    w3 = engine.solve(ROD, OPTICS, Orientation(0.3, 0.7, 1.9))
    xs = np.linspace(-3, 3, 7)
    ys = np.linspace(-2, 2, 7)
    a = w1.field_on_pixels((0.1, -0.2, 8.0), xs, ys)
    b = w3.field_on_pixels((0.1, -0.2, 8.0), xs, ys)
    assert np.abs(a[0] - b[0]).max() < 1e-12 * np.abs(a[0]).max()
    assert np.abs(a[0]).max() > 1e-3
    # a tilt does change it
    c = w2.field_on_pixels((0.1, -0.2, 8.0), xs, ys)
    assert np.abs(a[0] - c[0]).max() > 1e-2 * np.abs(a[0]).max()


def test_near_points_from_the_expansion_and_refused_inside_the_particle() -> None:
    wave = AxisymmetricTMatrix().solve(ROD, OPTICS, Orientation(0.0, 0.5, 0.0))
    r = ROD.bounding_radius_um
    near = np.array([[0.0, 0.0, 1.5 * r]])
    assert 1.5 < NEAR_ZONE
    far = np.array([[0.0, 0.0, 3.0 * r]])
    assert np.all(np.isfinite(wave.field_at(near)))
    assert np.all(np.isfinite(wave.field_at(far)))
    with pytest.raises(ValueError, match="circumscribing"):
        wave.field_at(np.array([[0.0, 0.0, 0.5 * r]]))


def test_provenance_and_file_round_trip(tmp_path) -> None:
    tm = build_exact_tmatrix(Spheroid(0.5, 1.0, 1.495), OPTICS)
    p = tm.provenance
    assert p["method"] == "ebcm" and p["engine"] == "exact"
    assert p["order"] == tm.order and tm.modulus == 2 * tm.order + 1
    assert p["tolerance_met"] and p["truncation_estimate"] <= 1e-5
    assert p["build_seconds"] > 0 and p["q_condition_max"] < 1e9
    path = save_tmatrix(tm, tmp_path / "spheroid.npz")
    back = load_tmatrix(path)
    assert back.order == tm.order and back.modulus == tm.modulus
    assert np.abs(back.dense() - tm.dense()).max() == 0.0


def test_tapered_cap_is_thinner_than_the_uniform_cap() -> None:
    """The crescent's shell is inside the uniform cap's and ends at z = t/2: its scattering
    lies between the bare core's and the uniform cap's."""
    prof = CapProfile(0.443, 0.047, 1.581, 2.74, tapered=True)
    assert prof.intervals(0.443 + 1e-9, 1.33)[0][0] == pytest.approx(0.047 / (2 * 0.443), 1e-6)
    assert prof.intervals(0.489, 1.33)[0][0] > 0.9
    core = build_exact_tmatrix(Sphere(0.443, 1.581), OPTICS, order=14)
    taper = build_exact_tmatrix(TaperedJanusSphere(0.443, 0.047, 1.581, 2.74), OPTICS, order=14)
    cap = build_exact_tmatrix(JanusSphere(0.443, 0.047, 1.581, 2.74), OPTICS, order=14)

    def forward(tm):
        c = tm.lab_coefficients((0.0, 0.0, 0.0), np.array([1.0, 0.0, 0.0]))
        return tm.expansion(c.vector).far_amplitude(np.array([[0.0, 0.0, -1.0]]))[0, 0]

    f0, f1, f2 = abs(forward(core)), abs(forward(taper)), abs(forward(cap))
    assert min(f0, f2) < f1 < max(f0, f2)


def test_rotation_derivatives_of_the_exact_wave_match_finite_differences() -> None:
    """Downstream reuse: the exact T-matrix's orientation derivatives (Wigner) are those of the
    field itself."""
    from holofit.conventions import euler_zyz, euler_zyz_from_matrix

    engine = AxisymmetricTMatrix()
    o = Orientation(0.4, 0.9, 0.0)
    wave = engine.solve(ROD, OPTICS, o)
    xs = np.linspace(-2.0, 2.0, 5)
    ys = np.linspace(-1.5, 1.5, 5)
    pos = (0.2, 0.1, 6.0)
    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    (ex, _), derivs = wave.field_and_rotation_derivatives(pos, xs, ys, [axis])
    h = 1e-5
    kx = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]],
                   [-axis[1], axis[0], 0.0]])
    fields = []
    for sign in (1.0, -1.0):
        rot = np.eye(3) + np.sin(sign * h) * kx + (1 - np.cos(sign * h)) * kx @ kx
        angles = euler_zyz_from_matrix(rot @ euler_zyz(*o.as_tuple()))
        fields.append(engine.solve(ROD, OPTICS, Orientation(*angles)).field_on_pixels(
            pos, xs, ys)[0])
    fd = (fields[0] - fields[1]) / (2 * h)
    assert np.abs(derivs[0][0] - fd).max() < 1e-5 * np.abs(fd).max()
    assert np.abs(fd).max() > 1e-3 * np.abs(ex).max()
    assert engine.builds == 1


def test_a_fit_builds_every_model_at_its_reference_discretisation() -> None:
    """A fit's engine keeps the reference build's order (and the imbedding's radial steps) for
    every size: a rod 10 % longer, searched on its own, takes another order; at the fixed one
    its far field is still within the stated accuracies of its own search's."""
    import math

    from holofit.scattering.axisym.order import far_field_change

    engine = AxisymmetricTMatrix()
    ref = Spherocylinder(0.5, 1.0, 1.495)
    d = engine.fix_discretisation(ref, OPTICS)
    assert engine.tmatrix(ref, OPTICS).order == d.order and engine.builds == 0
    assert d.method == "ebcm" and d.radial_steps is None and d.truncation_estimate > 0
    longer = Spherocylinder(0.5, 1.1, 1.495)
    own = build_exact_tmatrix(longer, OPTICS, max_seconds=math.inf)
    fixed = engine.tmatrix(longer, OPTICS)
    assert fixed.order == d.order != own.order and engine.builds == 1
    assert fixed.provenance["truncation_estimate"] == d.truncation_estimate
    stated = max(d.truncation_estimate, own.provenance["truncation_estimate"])
    assert far_field_change(fixed, own) < 3 * stated


def test_a_janus_fit_keeps_its_radial_steps_and_moves_smoothly_with_the_cap() -> None:
    """At the fixed discretisation the far field is a smooth function of the cap thickness: the
    finite differences of the fit's step (2 nm) and of twice it agree to first order."""
    janus = JanusSphere(0.443, 0.047, 1.581, 2.74)
    engine = AxisymmetricTMatrix()
    d = engine.fix_discretisation(janus, OPTICS)
    assert d.method == "iitm" and d.radial_steps is not None
    h = 2e-3

    def far(t: float) -> np.ndarray:
        tm = engine.tmatrix(JanusSphere(0.443, t, 1.581, 2.74), OPTICS)
        assert tm.provenance["radial_steps"] == list(d.radial_steps)
        c = tm.lab_coefficients((0.3, 0.8, 0.0), np.array([1.0, 0.0, 0.0]))
        dirs = np.array([[0.0, 0.0, -1.0], [0.3, 0.0, -0.954], [0.0, 0.5, -0.866]])
        return tm.expansion(c.vector).far_amplitude(dirs)

    f = {k: far(0.047 + k * h / 2) for k in (0, 1, 2, 4)}

    def slope(k: int) -> np.ndarray:  # forward difference of step k h / 2, per um
        return (f[k] - f[0]) / (k * h / 2)

    # smooth: the forward difference's error is first order in the step (it halves with it);
    # a jump of the discretisation between the sizes would not
    big, small = slope(2) - slope(4), slope(1) - slope(2)
    assert np.abs(slope(2)).max() > 1.0
    assert np.abs(big).max() < 0.1 * np.abs(slope(2)).max()
    assert 0.35 < np.abs(small).max() / np.abs(big).max() < 0.65


def test_a_janus_fits_radial_steps_stay_within_their_share_of_a_fine_integration() -> None:
    """The fit's plain-RK4 steps (fewer than the reference's) keep the far field within
    ``STEP_SHARE`` of the truncation estimate of an integration with four times the
    reference's steps and Richardson's extrapolation (independent of the step choice)."""
    from holofit.scattering.axisym.discretisation import (
        STEP_SHARE,
        Discretisation,
        reference_build,
    )
    from holofit.scattering.axisym.order import far_field_change

    janus = JanusSphere(0.443, 0.047, 1.581, 2.74)
    ref = reference_build(janus, OPTICS)
    d = Discretisation.of(ref)
    steps = ref.provenance["reference_radial_steps"]
    assert d.radial_steps is not None and not d.richardson
    assert d.radial_steps[0] < steps[0]  # the fit's build is cheaper than the reference's
    fine = build_exact_tmatrix(janus, OPTICS, order=d.order,
                               radial_steps=[4 * s for s in steps], estimate=False)
    change = far_field_change(ref, fine)
    assert change < STEP_SHARE * d.truncation_estimate
    # the fewest steps: a quarter fewer would be past the bar's half (RK4: steps^-4)
    assert change > 0.5 * STEP_SHARE * d.truncation_estimate * 0.75 ** 4
