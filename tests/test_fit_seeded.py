"""The initial pass's frames seeded from the start statics' T-matrix
(:mod:`holofit.fit.seeded`) and spread over the movie, on a small simulated rod whose particle
config starts 10-20 nm and 0.01 in index off the truth."""

from __future__ import annotations

import json

import numpy as np
import pytest

from holofit.batch.stage import FrameLoader
from holofit.config import load_instrument, load_particle, resolve_config
from holofit.crop import CropConfig, run_crop
from holofit.fit.config import FitConfig
from holofit.fit.frame import fit_frame
from holofit.fit.initial_pass import initial_choice, initial_particle
from holofit.fit.passes import load_payload
from holofit.fit.problem import FrameProblem
from holofit.fit.seeded import SEED_BUILD, fit_frame_seeded
from holofit.fit.settings import FrameFitSettings
from holofit.fit.stage import run_fit
from holofit.fit.task import free_parameters
from holofit.prefit import run_prefit
from holofit.simulate.holograms import simulate_movie
from holofit.tables.crop import merge_suspects
from holofit.tables.cropset import CropSet
from holofit.tables.fit import read_fit_table
from holofit.tables.inputs import read_stage_table
from tests.stage_helpers import ROD_TOML, SERIAL, crop_prefit_library

#: the fit's start: the truth (ROD_TOML: a 0.3, b 0.7, n 1.5) a little off
START_TOML = ROD_TOML.replace("a_um = 0.3", "a_um = 0.31").replace(
    "b_um = 0.7", "b_um = 0.68").replace("index = 1.5", "index = 1.49")
N_FRAMES = 8


def test_spread_frames_are_the_middles_of_equal_runs_clean_ones_first():
    frames = list(range(20))
    assert initial_choice(frames, [False] * 20, 4, spread=True) == [2, 7, 12, 17]
    assert initial_choice(frames, [False] * 20, 4) == [0, 1, 2, 3]
    over = [f % 2 == 0 for f in frames]  # the odd frames are clean
    assert initial_choice(frames, over, 2, spread=True) == [5, 15]
    # two overlapped frames needed: spread over the farther half of the overlapped ones
    assert initial_choice(frames, over, 12, spread=True) == sorted([2, 6, *range(1, 20, 2)])
    far = [float(f) for f in frames]  # the later, the farther the nearest neighbour
    assert initial_choice(frames, over, 12, spread=True, distance=far) == sorted(
        [12, 16, *range(1, 20, 2)])
    assert initial_choice(frames, over, 12, distance=far) == sorted([16, 18, *range(1, 20, 2)])
    assert initial_choice(frames, [False] * 20, 25, spread=True) == frames


def test_frames_that_may_hold_a_merged_neighbour_come_last():
    # a crossing: track 1 lost next to track 0 at frame 8, found again (as track 2) at 14;
    # track 0 looks alone in 8-13 but may hold both holograms there
    losses = [{"particle": 1, "kind": "lost", "first_frame": 8, "last_frame": 19,
               "neighbour": 0, "distance_um": 1.2},
              {"particle": 2, "kind": "late", "first_frame": 0, "last_frame": 13,
               "neighbour": 0, "distance_um": 1.5},
              {"particle": 2, "kind": "undetected", "first_frame": 16, "last_frame": 16,
               "neighbour": 0, "distance_um": 2.0}]
    suspects = merge_suspects(losses)
    assert suspects == {0: {8, 9, 10, 11, 12, 13, 16}}
    frames = list(range(20))
    over = [f < 8 or f > 13 for f in frames]  # the others' holograms reach into the crop
    far = [10.0 - f if f < 8 else f - 5.0 for f in frames]
    doubt = [f in suspects[0] for f in frames]
    got = initial_choice(frames, over, 4, spread=True, distance=far, suspect=doubt)
    assert not set(got) & suspects[0]
    # the farther half of the 13 overlapped frames (19, 18, 17, 0, 15, 1), spread
    assert got == [0, 15, 17, 19]
    assert set(initial_choice(frames, over, 19, distance=far, suspect=doubt)) == set(
        frames) - {16}
    # a loss with no partner: its whole span
    assert merge_suspects(losses[:1]) == {0: set(range(8, 20))}


@pytest.fixture(scope="module")
def movie(tmp_path_factory):
    """An 8-frame movie of the small rod at orientations all over the sphere, cropped,
    prefitted and with the library of the start particle."""
    root = tmp_path_factory.mktemp("seeded")
    (root / "truth.toml").write_text(ROD_TOML)
    (root / "start.toml").write_text(START_TOML)
    truth = load_particle(root / "truth.toml")
    start = load_particle(root / "start.toml")
    inst = load_instrument(resolve_config("paper_60x_water", "instruments"))
    rng = np.random.default_rng(5)
    pos = np.column_stack([8 + 0.2 * rng.normal(size=N_FRAMES), 8 + 0.2 * rng.normal(
        size=N_FRAMES), 9 + 0.3 * rng.normal(size=N_FRAMES)])
    angles = np.column_stack([rng.uniform(-np.pi, np.pi, N_FRAMES),
                              np.arccos(rng.uniform(-0.9, 0.9, N_FRAMES)),
                              np.zeros(N_FRAMES)])
    sim = simulate_movie(truth.model, inst, pos, (90, 90), orientations=angles, alpha=0.9,
                         theory=truth.theory(), seed=3, out_dir=root / "sim")
    crop_prefit_library(sim, inst, start, root)
    return root, start, inst, angles, pos


def _axis(theta, psi):
    return np.array([np.sin(theta) * np.cos(psi), np.sin(theta) * np.sin(psi), np.cos(theta)])


def test_a_seeded_frame_reaches_the_truth_with_fewer_solves(movie):
    """From the pose fitted on the start statics' T-matrix, the fit with every parameter free
    lands where the fit from the library's starts does (the truth), for fewer DDA solves."""
    root, start, inst, angles, pos = movie
    particle = initial_particle(start.with_fixed_lattice(inst.optics))
    model = particle.model
    seeding = particle.theory(fixed_lattice_for=inst.optics)
    seeding.tmatrix(model, inst.optics)
    crops = CropSet(root / "crop")
    pre, _ = read_stage_table(root / "prefit" / "prefit.csv", crops, "prefit")
    lib, _ = read_stage_table(root / "lib" / "library.csv", crops, "library")
    loader = FrameLoader(crops, pre, lib)
    opts = FrameFitSettings(stop_chi2=1.0)
    free = free_parameters(model, "initial")
    seeded_solves, library_solves = 0, 0
    for frame in (1, 4, 6):
        p = load_payload(loader, frame)
        at = (p.start["x_um"], p.start["y_um"], p.start["z_um"])
        direct = particle.theory(fixed_lattice_for=inst.optics)
        seeded = fit_frame_seeded(
            FrameProblem(
                p.crop,
                p.corner,
                inst.pixel_size_um,
                direct,
                model,
                inst.optics,
                free,
                settings=opts,
                seed=frame,
            ),
            seeding,
            at,
            p.start["alpha"],
            p.candidates,
        )
        direct = particle.theory(fixed_lattice_for=inst.optics)
        plain = fit_frame(
            FrameProblem(
                p.crop,
                p.corner,
                inst.pixel_size_um,
                direct,
                model,
                inst.optics,
                free,
                settings=opts,
                seed=frame,
            ),
            at,
            p.start["alpha"],
            p.candidates,
        )
        u_true = _axis(angles[frame, 1], angles[frame, 0])
        for r in (seeded, plain):
            assert r.status == "ok", r.message
            u = np.array([r.values[k] for k in ("ux", "uy", "uz")])
            assert np.degrees(np.arccos(min(abs(u @ u_true), 1.0))) < 2.0
            assert r.values["a_um"] == pytest.approx(0.3, abs=0.01)
            assert r.values["b_um"] == pytest.approx(0.7, abs=0.02)
            xyz = [r.values[k] for k in ("x_um", "y_um", "z_um")]
            np.testing.assert_allclose(xyz, pos[frame], atol=0.03)
        # the seed's T-matrix holograms are counted, its start columns are the library's
        assert seeded.n_eval > seeded.n_solves
        assert np.isfinite(seeded.extra["start_theta_rad"])
        assert abs(seeded.chi2 - plain.chi2) < 2.0 + 0.002 * plain.chi2
        seeded_solves += seeded.n_solves
        library_solves += plain.n_solves
    print("direct solves, seeded against library starts:", seeded_solves, library_solves)
    assert seeded_solves < 0.8 * library_solves, (seeded_solves, library_solves)


def test_the_initial_pass_is_seeded_and_spread_with_a_tmatrix(movie, tmp_path):
    """With a T-matrix (the default policy on 8 frames) the initial pass fits frames spread
    over the movie, seeded, and recovers the truth's statics; without one (``--tmatrix
    never``) it follows the track from the first frame, as before."""
    root, start, _, _, _ = movie
    run = run_fit(
        root / "crop",
        root / "prefit",
        root / "lib",
        tmp_path / "a",
        FitConfig(start, passes="initial", initial_frames=3, plot=False),
        batch=SERIAL,
    )
    assert (tmp_path / "a" / "tmatrix_start.npz").exists()
    built = json.loads((tmp_path / "a" / "tmatrix_start.npz.json").read_text())
    assert built["tolerance"] == SEED_BUILD["tolerance"]  # a seed's T-matrix, not a final one
    assert any(
        "initial pass's poses (start statics) served from the particle's T-matrix" in n
        for n in run.notes
    ), run.notes
    table = read_fit_table(run.initial).table
    assert table["frame"].tolist() == [1, 4, 6]
    assert (table["status"] == "ok").all(), table["message"].tolist()
    static = json.loads(run.static.read_text())["values"]
    assert static["a_um"] == pytest.approx(0.3, abs=0.01)
    assert static["b_um"] == pytest.approx(0.7, abs=0.02)
    assert static["n"] == pytest.approx(1.5, abs=0.005)
    # a rerun finds the seeds' T-matrix and every frame done, and changes nothing
    before = run.initial.read_bytes()
    again = run_fit(
        root / "crop",
        root / "prefit",
        root / "lib",
        tmp_path / "a",
        FitConfig(start, passes="initial", initial_frames=3, plot=False),
        batch=SERIAL,
    )
    assert again.summaries["initial"].n_run == 0 and again.initial.read_bytes() == before
    assert any("initial pass's poses" in n and "loaded" in n for n in again.notes), again.notes
    never = run_fit(
        root / "crop",
        root / "prefit",
        root / "lib",
        tmp_path / "b",
        FitConfig(start, passes="initial", initial_frames=3, tmatrix="never", plot=False),
        batch=SERIAL,
    )
    assert not (tmp_path / "b" / "tmatrix_start.npz").exists()
    assert read_fit_table(never.initial).table["frame"].tolist() == [0, 1, 2]


def test_a_seed_from_the_twin_height_is_tried_from_other_heights(tmp_path):
    """The rod 1.5 um above the focal plane with the prefit's height at its twin 1.5 um below
    (the Janus replicate's prefit did this near focus): the seed's pose fit is far from the
    data, so it is tried from other heights until one fits, and the full fit lands on the
    truth; without the retries (``retry_chi2_red`` infinite) the frame's fit stays at the twin
    or is not ``ok``."""
    from holofit.library.search import Candidate

    (tmp_path / "truth.toml").write_text(ROD_TOML)
    (tmp_path / "start.toml").write_text(START_TOML)
    truth = load_particle(tmp_path / "truth.toml")
    inst = load_instrument(resolve_config("paper_60x_water", "instruments"))
    pos = np.array([[8.0, 8.0, 1.5]])
    angle = np.array([[0.7, 1.1, 0.0]])
    sim = simulate_movie(
        truth.model,
        inst,
        pos,
        (90, 90),
        orientations=angle,
        alpha=0.9,
        theory=truth.theory(),
        seed=4,
        out_dir=tmp_path / "sim",
    )
    run_crop(sim.movie, sim.background, inst, tmp_path / "crop", CropConfig(size=64, plot=False))
    run_prefit(tmp_path / "crop", tmp_path / "prefit", batch=SERIAL, plot=False)
    crops = CropSet(tmp_path / "crop")
    pre, _ = read_stage_table(tmp_path / "prefit" / "prefit.csv", crops, "prefit")
    p = load_payload(FrameLoader(crops, pre), 0)
    particle = initial_particle(
        load_particle(tmp_path / "start.toml").with_fixed_lattice(inst.optics)
    )
    model = particle.model
    seeding = particle.theory(fixed_lattice_for=inst.optics)
    seeding.tmatrix(model, inst.optics)
    starts = (Candidate(0.7, 1.1, 0.0, 0.9),)
    results = {}
    for retry in (1.5, np.inf):
        direct = particle.theory(fixed_lattice_for=inst.optics)
        results[retry] = fit_frame_seeded(
            FrameProblem(
                p.crop,
                p.corner,
                inst.pixel_size_um,
                direct,
                model,
                inst.optics,
                free_parameters(model, "initial"),
                settings=FrameFitSettings(stop_chi2=1.0),
            ),
            seeding,
            (p.start["x_um"], p.start["y_um"], -1.5),
            p.start["alpha"],
            starts,
            retry_chi2_red=retry,
        )
    good, bad = results[1.5], results[np.inf]
    assert good.status == "ok" and good.values["z_um"] == pytest.approx(1.5, abs=0.05)
    assert good.values["a_um"] == pytest.approx(0.3, abs=0.01)
    u = np.array([good.values[k] for k in ("ux", "uy", "uz")])
    assert np.degrees(np.arccos(min(abs(u @ _axis(1.1, 0.7)), 1.0))) < 2.0
    assert bad.status != "ok" or abs(bad.values["z_um"] - 1.5) > 0.5
    assert good.chi2 < bad.chi2
