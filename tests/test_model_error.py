"""The model-error estimate of a fit table (:mod:`holofit.fit.model_error`): the rule against a
known convergence law, the frames it picks, and (slow) that it finds the DDA's known bias on an
exact coated-sphere hologram."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from holofit.fit.model_error import (
    ModelErrorSettings,
    choose_frames,
    estimate_model_error,
    exact_accuracy,
    model_error_note,
)


def test_the_estimate_recovers_the_default_rules_offset_under_its_law() -> None:
    """Fits that follow p(d) = p* + C d^q exactly (the law the estimate assumes): the estimate
    is the default's offset C d^q from the limit, whatever the refinement, for q = 1; a wrong
    assumed order misstates it by the known ratio."""
    rng = np.random.default_rng(3)
    truth = {"n": 1.59, "a_um": 0.5}
    slope = {"n": 0.02, "a_um": -0.3}  # per um of dipole size
    d = 0.044
    for refine in (1.25, 2.0):
        rows = {}
        for rule, size in (("default", d), ("finer", d / refine)):
            noise = rng.normal(0.0, 1e-9, size=(3, 2))
            rows[rule] = pd.DataFrame({k: truth[k] + slope[k] * size + noise[:, i]
                                       for i, k in enumerate(truth)})
        rows["default"]["d_n"] = 1e-4
        rows["default"]["d_a_um"] = 2e-3
        got = estimate_model_error(rows["default"], rows["finer"], ["n", "a_um"], refine)
        for k in truth:
            assert got[k]["estimate"] == pytest.approx(slope[k] * d, rel=1e-5)
            assert got[k]["change_mean"] == pytest.approx(slope[k] * d * (1 - 1 / refine),
                                                          rel=1e-5)
            assert len(got[k]["changes"]) == 3
        assert got["n"]["estimate_over_sigma"] == pytest.approx(0.02 * d / 1e-4, rel=1e-5)
    # a quadratic law read as a linear one: (1 - 1/4) / (1 - 1/2) = 1.5 times too large
    quad = pd.DataFrame({"n": [1.0 + 0.02 * d**2]})
    finer = pd.DataFrame({"n": [1.0 + 0.02 * (d / 2) ** 2]})
    got = estimate_model_error(quad, finer, ["n"], 2.0)
    assert got["n"]["estimate"] == pytest.approx(1.5 * 0.02 * d**2, rel=1e-9)
    assert np.isnan(got["n"]["change_sd"]) and np.isnan(got["n"]["sigma"])


def test_frames_are_spread_over_the_rows() -> None:
    keys = [(0, f) for f in range(30)] + [(1, f) for f in range(10)]
    picked = choose_frames(keys, 4)
    assert len(picked) == 4 and picked == sorted(picked)
    assert picked[0][1] >= 3 and picked[-1] == (1, 5)
    assert choose_frames(keys[:2], 3) == keys[:2]
    with pytest.raises(ValueError, match="frames"):
        ModelErrorSettings(frames=0)
    with pytest.raises(ValueError, match="finer"):
        ModelErrorSettings(refine=0.5)


def test_the_exact_engines_entry_is_its_builds_stated_accuracy() -> None:
    from holofit.optics import Optics
    from holofit.particles import Spheroid
    from holofit.scattering.axisym import build_exact_tmatrix

    tm = build_exact_tmatrix(Spheroid(0.3, 0.5, 1.5), Optics(0.66, 1.33))
    entry = exact_accuracy(tm.provenance)
    assert entry["truncation_estimate"] == tm.provenance["truncation_estimate"] <= 1e-5
    assert entry["method"] == "ebcm" and entry["order"] == tm.order
    assert "exact engine" in model_error_note(entry)


@pytest.mark.slow
def test_the_refits_find_the_dda_bias_of_an_exact_coated_sphere_hologram() -> None:
    """An exact coated-sphere hologram (coated Lorenz-Mie, no dipoles) with the paper's 47 nm
    TiO2 shell, fitted by the DDA at its default rule (the shell two dipoles thick): every
    parameter is biased by many sigma. The model-error refits (the module's own frame task)
    see it: the estimate has the bias's sign for every parameter, is many sigma, is not below
    half the bias, and is within ten times it for most parameters."""
    from holofit.config import Instrument, ParticleConfig
    from holofit.conventions import DetectorGrid
    from holofit.dda.settings import DDASettings
    from holofit.engines.registry import get_engine
    from holofit.fit.model_error import RefitConfig, RefitPayload, refit_task
    from holofit.fit.settings import FrameFitSettings
    from holofit.fit.task import PassConfig
    from holofit.hologram import hologram
    from holofit.optics import Optics
    from holofit.particles import CoatedSphere

    truth = CoatedSphere(0.25, 0.047, 1.59, 2.7)
    optics = Optics(0.660, 1.33)
    px = 0.1
    pos = (3.2, 3.2, 7.0)
    data = hologram(truth, pos, DetectorGrid((64, 64), px), optics,
                    theory=get_engine("coated_sphere"))
    d0 = DDASettings().dipole_size_for(truth, optics)
    particle = ParticleConfig(truth, {"dda": {"dipole_size_um": d0}})
    inst = Instrument("test", optics.wavelength_um, optics.n_medium, px)
    noise = 0.01  # the noise the sigmas are in units of (the data themselves are exact)
    cfg = PassConfig(particle, inst, "final", FrameFitSettings(noise_sd=noise), "builtin")
    start = {"x_um": pos[0], "y_um": pos[1], "z_um": pos[2], "alpha": 1.0,
             "radius_um": 0.25, "shell_thickness_um": 0.047, "n_core": 1.59, "n_shell": 2.7}
    row = refit_task(RefitConfig(cfg, 1.25), (0, 0), RefitPayload(data, (0, 0), start))
    assert row["status"] == "ok", row["message"]
    names = ["z_um", "alpha", "radius_um", "shell_thickness_um", "n_core", "n_shell"]
    default = pd.DataFrame([{**{n: row[n] for n in names},
                             **{f"d_{n}": row[f"d_{n}"] for n in names}}])
    finer = pd.DataFrame([{n: row[f"{n}_fine"] for n in names}])
    got = estimate_model_error(default, finer, names, 1.25)
    ratios = []
    for n in names:
        bias = row[n] - start[n]
        sigma = row[f"d_{n}"]
        assert abs(bias) > 5 * sigma, n  # the DDA's bias at its default rule
        est = got[n]["estimate"]
        # the estimate's sign is the bias's, and it does not understate it by more than 2x
        # (measured: it overstates the thin shell's index 36x, the others 1.3-6x: the shell's
        # error is not monotone in d at two dipoles across)
        assert est / bias > 0.5, (n, est, bias)
        assert abs(got[n]["estimate_over_sigma"]) > 5.0, n
        ratios.append(est / bias)
    assert float(np.median(ratios)) < 10.0, ratios
