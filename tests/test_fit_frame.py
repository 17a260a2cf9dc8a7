"""DDA fit of one frame, against holograms of known truth: convergence from library-grade
starts, static parameters in the initial pass, uncertainties against the scatter over noise
draws, the runner-up and the ambiguity flag."""

from __future__ import annotations

import math

import numpy as np
import pytest

from holofit.camera import Camera
from holofit.conventions import DetectorGrid
from holofit.dda.engine import BuiltinDDA
from holofit.fit.frame import fit_frame
from holofit.fit.problem import FrameProblem
from holofit.fit.settings import FrameFitSettings
from holofit.hologram import calc_hologram
from holofit.library.search import Candidate
from holofit.optics import Optics
from holofit.particles import Spherocylinder
from holofit.scattering.theory import Orientation

OPTICS = Optics(0.66, 1.33, 0.0)
PX = 0.12
GRID = DetectorGrid((64, 64), PX, (100, 200))
ROD = Spherocylinder(0.3, 0.7, 1.5)
TRUTH = {"x_um": (200 + 32.2) * PX, "y_um": (100 + 31.7) * PX, "z_um": 8.0, "alpha": 0.9,
         "theta_rad": 0.9, "psi_rad": 0.4}
FINAL = ("x_um", "y_um", "z_um", "orientation", "alpha")


@pytest.fixture(scope="module")
def engine():
    return BuiltinDDA(dipole_size_um=0.09, tolerance=1e-7)


def _hologram(engine, model=ROD, truth=TRUTH):
    wave = engine.solve(model, OPTICS, Orientation(truth["psi_rad"], truth["theta_rad"]))
    return calc_hologram(wave, (truth["x_um"], truth["y_um"], truth["z_um"]), GRID,
                         truth["alpha"])


def _fit(engine, data, free=FINAL, model=ROD, start_off=(0.05, -0.04, 0.25),
         cands=None, **opts):
    cands = cands or [Candidate(TRUTH["psi_rad"] + 0.08, TRUTH["theta_rad"] - 0.1, 0.0, 0.95)]
    start = (TRUTH["x_um"] + start_off[0], TRUTH["y_um"] + start_off[1],
             TRUTH["z_um"] + start_off[2])
    return fit_frame(
        FrameProblem(
            data,
            GRID.corner,
            PX,
            engine,
            model,
            OPTICS,
            free,
            settings=FrameFitSettings(**opts),
            seed=1,
        ),
        start,
        0.85,
        cands,
    )


def test_noise_free_frame_converges_to_the_truth_from_a_library_grade_start(engine):
    res = _fit(engine, _hologram(engine), mirror=False, noise_sd=1e-3)
    assert res.status == "ok", res.message
    for key in ("x_um", "y_um", "z_um", "alpha"):
        assert abs(res.values[key] - TRUTH[key]) < 2e-5, key
    assert abs(res.values["theta_rad"] - TRUTH["theta_rad"]) < 2e-5
    assert abs(res.values["psi_rad"] - TRUTH["psi_rad"]) < 2e-5
    assert res.r2 > 1 - 1e-9 and res.extra["n_solves"] > 0


def test_initial_pass_recovers_the_static_parameters(engine):
    start_model = Spherocylinder(0.315, 0.68, 1.51)
    res = _fit(
        engine,
        _hologram(engine),
        free=(*FINAL, "a_um", "b_um", "n"),
        model=start_model,
        mirror=False,
        noise_sd=1e-3,
    )
    assert res.status == "ok", res.message
    assert abs(res.values["a_um"] - 0.3) < 1e-4
    assert abs(res.values["b_um"] - 0.7) < 1e-4
    assert abs(res.values["n"] - 1.5) < 1e-4
    assert abs(res.values["z_um"] - 8.0) < 1e-4


def test_uncertainties_match_the_scatter_over_noise_draws(engine):
    clean = _hologram(engine)
    cam = Camera(background_counts=120.0, electrons_per_count=10.0)
    fits = []
    for seed in range(8):
        raw = cam.expose(clean, np.random.default_rng(seed))
        fits.append(_fit(engine, raw / 120.0, mirror=False))
    assert all(f.status == "ok" for f in fits)
    for key in ("z_um", "theta_rad"):
        values = np.array([f.values[key] for f in fits])
        sigma = np.mean([f.errors[key] for f in fits])
        scatter = values.std(ddof=1)
        assert 0.4 < scatter / sigma < 2.0, (key, scatter, sigma)
        assert abs(values.mean() - TRUTH[key]) < 4 * sigma, key
    assert 0.8 < np.mean([f.chi2_red for f in fits]) < 1.2


def test_mirrored_start_gives_a_runner_up_and_a_decisive_frame_is_not_ambiguous(engine):
    res = _fit(engine, _hologram(engine), noise_sd=1e-3)
    assert res.status == "ok", res.message
    assert res.extra["n_starts"] == 2
    assert abs(res.values["theta_rad"] - TRUTH["theta_rad"]) < 1e-4
    if not math.isnan(res.extra["delta_chi2"]):
        # the mirror image through the x-y plane is another minimum, clearly worse here
        assert res.extra["delta_chi2"] > 9 and res.extra["ambiguous"] == 0
        assert abs(res.extra["runner_up_theta_rad"] - TRUTH["theta_rad"]) > 0.05


def test_a_noise_level_difference_is_flagged_ambiguous(engine):
    # with noise 100x larger, the same two minima can no longer be told apart
    res = _fit(engine, _hologram(engine), noise_sd=1.0)
    assert res.extra["n_starts"] == 2
    if not math.isnan(res.extra["delta_chi2"]):
        assert res.extra["ambiguous"] == 1 and res.extra["delta_chi2"] < 9


def test_the_fits_of_a_frame_share_their_solved_orientations():
    # screening, best fit and runner-up of one frame solve each orientation once (the fits
    # share one cache of solved waves; an empty cache handed over used to start a new one)
    from tests.tracking_helpers import FINAL as FINAL_PASS
    from tests.tracking_helpers import INSTRUMENT, make_track
    from tests.tracking_helpers import ROD as SMALL_ROD
    from tests.tracking_helpers import engine as tm_engine

    theory = tm_engine()
    f = make_track(theory, n=1, seed=3).frames[0]
    keys: list[bytes] = []
    solve = theory.solve

    def counting(model, optics, orientation=None):
        keys.append(np.round([orientation.psi, orientation.theta, orientation.phi], 12).tobytes())
        return solve(model, optics, orientation)

    theory.solve = counting
    res = fit_frame(
        FrameProblem(
            f.crop,
            f.corner,
            INSTRUMENT.pixel_size_um,
            theory,
            SMALL_ROD,
            INSTRUMENT.optics,
            FINAL_PASS,
            settings=FrameFitSettings(),
            seed=0,
        ),
        f.position_um,
        f.alpha,
        f.candidates,
    )
    assert res.status == "ok" and res.extra["n_solves"] == len(keys) > 2
    assert len(set(keys)) == len(keys), "an orientation was solved twice"


def test_the_initial_pass_stop_keeps_the_statics_within_a_standard_error(engine):
    """``stop_chi2`` 1 (the initial pass's, holofit.fit.stage.INITIAL_STOP_CHI2) on a noisy
    frame with every static free: the statics and the position land within one standard error
    of the tight fit's minimum, with fewer DDA solves."""
    rng = np.random.default_rng(5)
    data = _hologram(engine) + rng.normal(0.0, 0.02, GRID.shape)
    start_model = Spherocylinder(0.315, 0.68, 1.51)
    free = (*FINAL, "a_um", "b_um", "n")
    fits = [
        _fit(engine, data, free=free, model=start_model, mirror=False, stop_chi2=stop)
        for stop in (0.0, 1.0)
    ]
    tight, stopped = fits
    assert tight.status == stopped.status == "ok"
    for key in ("a_um", "b_um", "n", "x_um", "y_um", "z_um", "theta_rad"):
        assert abs(stopped.values[key] - tight.values[key]) < tight.errors[key], key
    assert stopped.chi2 - tight.chi2 < 1.5  # chi^2 units of the pixel noise
    assert stopped.extra["n_solves"] < tight.extra["n_solves"]
