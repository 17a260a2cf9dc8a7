"""When a converged fit is not plain ``ok``: the quality rules on known truth.

A fit that ends outside the range the user searched is ``poor_fit`` even when it matches the
data (the hologram says the particle is not what the user said it is); a frame whose reduced
chi^2 is far above the movie's typical one is flagged by the movie-median rule
(:func:`holofit.quality.flag_outliers`), once, and the analysis leaves it out; a faint particle
fitted down to the camera noise is ``ok`` whatever its R^2.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from holofit.prefit.estimate import SearchSpace
from holofit.quality import flag_outliers
from holofit.status import OK, POOR_FIT
from tests.test_prefit_fit import TRUTH, _fit, _hologram


def test_a_fit_outside_the_searched_radius_range_is_poor_even_when_it_matches():
    # the truth (a = 0.65 um) lies above the range searched (0.2-0.5 um, 5 % margin: 0.525)
    fit = _fit(_hologram(), search=SearchSpace(radius_range_um=(0.2, 0.5)))
    assert fit.status == POOR_FIT
    assert "radius_um" in fit.message and "outside" in fit.message, fit.message
    # within the default range the same hologram is ok (the rule, not the fit, decided)
    assert _fit(_hologram()).status == OK
    assert abs(fit.values["radius_um"] - TRUTH["radius_um"]) < 0.01 or fit.r2 < 0.99


def _table(chi2_red: list[float], status: list[str] | None = None) -> pd.DataFrame:
    n = len(chi2_red)
    return pd.DataFrame({"frame": np.arange(n), "chi2_red": chi2_red,
                         "status": status or [OK] * n, "message": [""] * n})


def test_frames_far_above_the_movies_median_chi2_are_flagged_once():
    rng = np.random.default_rng(4)
    chi = list(1.0 + 0.1 * rng.standard_normal(30))
    chi[7], chi[19] = 4.5, 12.0  # 4.5x and 12x the median of ~1
    table = _table(chi)
    assert flag_outliers(table, factor=4.0) == 2
    assert table.loc[[7, 19], "status"].eq(POOR_FIT).all()
    assert table["message"][19].startswith("reduced chi2 more than 4 times the movie's median")
    assert (table.drop(index=[7, 19])["status"] == OK).all()
    # the median is over every converged row, so a second pass changes nothing
    assert flag_outliers(table, factor=4.0) == 0
    # too few converged rows for a meaningful median: nothing is flagged
    assert flag_outliers(_table([1.0] * 5 + [50.0]), factor=4.0) == 0


def test_a_faint_sphere_fitted_down_to_the_noise_is_ok_with_honest_errors():
    """A small, low-contrast sphere (0.25 um, n 1.45, 12 um up): its fringes barely stand
    above the camera noise (R^2 about 0.4), the fit explains the data to the noise (reduced
    chi^2 about 1). It is ``ok``, and its errors cover the truth: a low R^2 is no reason to
    call a fit poor."""
    from holofit.camera import Camera

    truth = {**TRUTH, "radius_um": 0.25, "n": 1.45}
    cam = Camera(background_counts=120.0)
    for seed in range(3):
        data = cam.expose(_hologram(truth), np.random.default_rng(seed)) / 120.0
        fit = _fit(data)
        assert fit.r2 < 0.5 and abs(fit.chi2_red - 1.0) < 0.1
        assert fit.status == OK, fit.message
        for key in ("radius_um", "n", "z_um"):
            assert abs(fit.values[key] - truth[key]) < 3 * fit.errors[key], key
    # the same camera without a particle: the fit explains nothing beyond a flat background
    empty = _fit(cam.expose(np.ones_like(_hologram(truth)), np.random.default_rng(9)) / 120.0)
    assert empty.status == POOR_FIT and "no particle" in empty.message, empty.message
