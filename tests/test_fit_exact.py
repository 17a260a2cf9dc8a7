"""The library and fit stages with the exact engine (``auto``'s choice for a rod) on a small rod
movie made by an independent engine's truth (the rod's own exact T-matrix at a higher order than
the fit's), and the model-error entries of the fit tables: the exact build's stated accuracy,
and the DDA's refits."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from holofit.config import load_instrument, load_particle, resolve_config
from holofit.fit.config import FitConfig
from holofit.fit.model_error import ModelErrorSettings
from holofit.fit.stage import run_fit
from holofit.scattering.axisym import AxisymmetricTMatrix
from holofit.simulate.holograms import simulate_movie
from tests.stage_helpers import ROD_TOML, SERIAL, crop_prefit_library

#: the small rod of the stage tests with ``auto``'s engine: its exact T-matrix
EXACT_TOML = ROD_TOML.replace('engine = "builtin"\n', "")
ANGLES = np.radians([[30, 50, 0], [34, 53, 0], [38, 49, 0]])
POSITIONS = np.array([[8.0, 8.0, 9.0], [8.1, 7.9, 9.2], [7.9, 8.05, 9.1]])


@pytest.fixture(scope="module")
def exact_movie(tmp_path_factory):
    """Three frames of the small rod from its exact T-matrix at a fixed order four above the
    fit's, cropped, prefitted and through the library (``auto``: the exact engine)."""
    root = tmp_path_factory.mktemp("exactrod")
    (root / "rod.toml").write_text(EXACT_TOML)
    particle = load_particle(root / "rod.toml")
    inst = load_instrument(resolve_config("paper_60x_water", "instruments"))
    fit_order = particle.theory(fixed_lattice_for=inst.optics).discretisation.order
    truth = AxisymmetricTMatrix()
    truth.tmatrix(particle.model, inst.optics, order=fit_order + 4)
    sim = simulate_movie(particle.model, inst, POSITIONS, (90, 90), orientations=ANGLES,
                         alpha=0.9, theory=truth, seed=2, out_dir=root / "sim")
    crop_prefit_library(sim, inst, particle, root)
    return root, particle


@pytest.fixture(scope="module")
def exact_fit(exact_movie, tmp_path_factory):
    """``auto``'s fit of the three frames (the exact engine), all three in the initial pass."""
    root, particle = exact_movie
    out = tmp_path_factory.mktemp("exactfit") / "fit"
    run = run_fit(root / "crop", root / "prefit", root / "lib", out,
                  FitConfig(particle, initial_frames=3, plot=False), batch=SERIAL)
    return run, out


def test_auto_fits_a_rod_with_its_exact_tmatrix_and_states_its_accuracy(exact_movie, exact_fit,
                                                                        tmp_path):
    root, particle = exact_movie
    run, out = exact_fit
    lib = pd.read_csv(root / "lib" / "library.csv")
    assert (lib["status"] == "ok").all()
    assert not (root / "lib" / "tilts.npz").exists()
    static = json.loads(run.static.read_text())
    assert static["values"]["a_um"] == pytest.approx(0.3, abs=0.005)
    assert static["values"]["b_um"] == pytest.approx(0.7, abs=0.005)
    assert static["values"]["n"] == pytest.approx(1.5, abs=0.005)
    table = pd.read_csv(run.final)
    assert (table["status"] == "ok").all(), table["message"].tolist()
    np.testing.assert_allclose(table[["x_um", "y_um", "z_um"]], POSITIONS, atol=0.01)
    # the initial pass (sizes and index free) ran on the exact engine, seeded from its
    # T-matrix (written by the driver), and the final pass served from the settled statics'
    assert (out / "tmatrix_start.npz").exists() and (out / "tmatrix.npz").exists()
    assert any(n.startswith("initial pass's poses") and "exact engine's T-matrix" in n
               for n in run.notes), run.notes
    assert any(n.startswith("final pass served from the exact engine's T-matrix")
               for n in run.notes), run.notes
    # the model error: in the sidecar, and in the stage's report (notes and run.as_dict())
    meta = json.loads((out / "fit.csv.json").read_text())
    entry = meta["model_error"]
    assert entry["method"] == "ebcm" and entry["kind"].startswith("exact")
    provenance = json.loads((out / "tmatrix.npz.json").read_text())
    assert entry["truncation_estimate"] == provenance["truncation_estimate"] > 0
    assert entry["order"] == provenance["order"]
    assert run.model_error == entry and any("model error: exact" in n for n in run.notes)
    assert run.as_dict()["model_error"] == entry
    # the DDA stays selectable on the same run: --engine builtin, with its model error off
    dda = run_fit(root / "crop", root / "prefit", root / "lib", tmp_path / "dda",
                  FitConfig(particle, engine="builtin", passes="final", static=run.static,
                            model_error=ModelErrorSettings(enabled=False), plot=False),
                  batch=SERIAL)
    sidecar = json.loads((tmp_path / "dda" / "fit.csv.json").read_text())
    assert "model_error" not in sidecar and sidecar["config"]["engine"] == "builtin"
    assert (pd.read_csv(dda.final)["status"] == "ok").all()
    assert not any("exact engine" in n for n in dda.notes), dda.notes


#: the small rod's lengths (the estimate bounds their model error; not the index's: docstring)
STATICS = ("a_um", "b_um")


def test_the_dda_fit_table_carries_its_refits(exact_movie, exact_fit, tmp_path):
    """A DDA run (the config names the built-in engine): fit.csv's sidecar has the refits'
    estimate for every fitted parameter, from the initial pass's frames, and a rerun reads it
    back without refitting. The independent check: the DDA's actual model error on the same
    frames, its statics minus the exact engine's fit of them (the movie is the exact rod's).
    Measured (d = 100 nm, 3 frames, the DDA's plane-fraction filling of main): estimate a
    -12.2, b -9.2 nm, n -1.8e-3 against the actual -3.8, -1.8 nm, +3.1e-3: the lengths' signs
    right and their estimate 3-5 times the actual (asserted: above it, within ten times), the
    index's sign wrong and its size 0.6 times the actual (not asserted: the estimate does not
    bound the index's model error). So the estimate is a size of the model error, not a
    signed correction, and for the index not even a bound."""
    root, _ = exact_movie
    (tmp_path / "dda.toml").write_text(ROD_TOML)
    dda = load_particle(tmp_path / "dda.toml")
    config = FitConfig(dda, initial_frames=3, plot=False,
                       model_error=ModelErrorSettings(frames=3))
    run = run_fit(root / "crop", root / "prefit", root / "lib", tmp_path / "fit", config,
                  batch=SERIAL)
    entry = json.loads((tmp_path / "fit" / "fit.csv.json").read_text())["model_error"]
    assert entry["kind"] == "DDA rule change" and entry["refine"] == 1.25
    assert entry["dipole_size_um"] == pytest.approx(0.1)
    initial = pd.read_csv(tmp_path / "fit" / "initial.csv")
    assert sorted(map(tuple, entry["frames"])) == sorted(
        zip(initial["particle"], initial["frame"], strict=True))
    params = entry["parameters"]
    assert {"z_um", "a_um", "b_um", "n", "alpha"} <= set(params)
    refits = pd.read_csv(tmp_path / "fit" / "model_error.csv")
    for name, v in params.items():
        assert len(v["changes"]) == 3 and np.isfinite(v["estimate"])
        # the changes are the refits' own (default rule - finer rule), scaled by 1 / (1 - 0.8)
        np.testing.assert_allclose(v["changes"], refits[name] - refits[f"{name}_fine"])
        assert v["estimate"] == pytest.approx(np.mean(v["changes"]) / 0.2)
    assert any(n.startswith("model error of the DDA") for n in run.notes)
    assert run.as_dict()["model_error"] == entry
    # the independent check against the exact engine's fit of the same frames
    exact_run, exact_out = exact_fit
    assert sorted(pd.read_csv(exact_out / "initial.csv")["frame"]) == sorted(initial["frame"])
    mine = json.loads(run.static.read_text())["values"]
    exact = json.loads(exact_run.static.read_text())["values"]
    for name in STATICS:
        actual = mine[name] - exact[name]
        assert abs(params[name]["estimate"]) > abs(actual), (name, params[name], actual)
        assert abs(params[name]["estimate"]) < 10 * abs(actual), (name, params[name], actual)
    again = run_fit(root / "crop", root / "prefit", root / "lib", tmp_path / "fit", config,
                    batch=SERIAL)
    assert again.summaries["final"].n_run == 0 and again.model_error == entry
