"""Issue 22: a movie of several particles through crop (tracks), prefit, library keys and the
fit per track; the truth is the simulation's (holofit.simulate.field_of_view)."""

from __future__ import annotations

import shutil

import numpy as np
import pandas as pd
import pytest
import tifffile

from holofit.config import load_instrument, load_particle, resolve_config
from holofit.crop import CropConfig, run_crop
from holofit.crop.errors import CropError
from holofit.crop.track_crops import link_detections, track_rows
from holofit.crop.tracks import LinkSettings
from holofit.particles import Sphere
from holofit.prefit.stage import run_prefit
from holofit.simulate.field_of_view import ParticleInView, simulate_field_of_view
from holofit.tables.cropset import CropSet, CropSetError

N = 16
SHAPE = (192, 240)
SIZE = 64
ENTERS = 6


@pytest.fixture(scope="module")
def inst():
    return load_instrument(resolve_config("paper_100x_oil", "instruments"))


@pytest.fixture(scope="module")
def scene(tmp_path_factory, inst):
    """Three spheres of three sizes diffusing ~10 um apart; the third enters at frame 6 (it is
    far outside the frame before)."""
    out = tmp_path_factory.mktemp("fov")
    rng = np.random.default_rng(1)

    def walk(x0, y0, z):
        w = 0.02 * np.cumsum(rng.normal(size=(N, 2)), axis=0)
        return np.column_stack([x0 + w[:, 0], y0 + w[:, 1], np.full(N, z)])

    pc = walk(10.0, 14.0, 11.0)
    pc[:ENTERS, 0] = -30.0
    particles = [ParticleInView(Sphere(0.5, 1.59), walk(5.0, 5.0, 10.0)),
                 ParticleInView(Sphere(0.4, 1.59), walk(16.0, 5.0, 12.0)),
                 ParticleInView(Sphere(0.6, 1.45), pc)]
    sim = simulate_field_of_view(particles, inst, SHAPE, out_dir=out / "sim", seed=3)
    crop = run_crop(sim.movie, sim.background, inst, out / "crop",
                    CropConfig(size=SIZE, plot=False))
    return out, sim, crop


def _track_to_truth(frames: pd.DataFrame, truth: pd.DataFrame) -> dict[int, int]:
    """Each track's true particle: the one nearest its centre in every frame (no swap)."""
    mapping = {}
    for p, track in frames[frames["status"] == "ok"].groupby("particle"):
        owners = set()
        for row in track.itertuples():
            here = truth[truth["frame"] == row.frame]
            d = np.hypot(here["x_px"] - row.x_px, here["y_px"] - row.y_px)
            assert d.min() < 1.0  # within a pixel of a true centre
            owners.add(int(here["particle"].iloc[int(np.argmin(d.to_numpy()))]))
        assert len(owners) == 1, f"track {p} holds particles {owners}"
        mapping[int(p)] = owners.pop()
    return mapping


def test_every_particle_is_a_track_with_no_swap(scene):
    _, sim, crop = scene
    frames = crop.frames
    assert sorted(frames["particle"].unique()) == [0, 1, 2]
    mapping = _track_to_truth(frames, sim.truth)
    assert sorted(mapping.values()) == [0, 1, 2]
    spans = frames.groupby("particle")["frame"].agg(["min", "max", "size"])
    entering = mapping_inverse(mapping, 2)
    # the particle that enters starts a track at its first frame in view
    assert spans.loc[entering].tolist() == [ENTERS, N - 1, N - ENTERS]
    assert (frames["status"] == "ok").all()
    # ~10 um apart, each sphere's fringes (above the noise out to ~10 um at 100x) reach into
    # the others' 6.8-um crops: every row overlaps another track's hologram (issue 36)
    assert frames["overlap"].all() and (frames["n_overlapping"] >= 1).all()
    with CropSet(crop.out_dir) as crops:
        assert crops.multi and crops.key_columns == ("particle", "frame")
        assert len(crops.keys) == len(frames)
        row = frames.iloc[5]
        key = (int(row["particle"]), int(row["frame"]))
        assert crops.row(key)["x_px"] == pytest.approx(row["x_px"])
        with pytest.raises(CropSetError, match="particle, frame"):
            crops.row(3)


def test_prefit_is_keyed_by_particle_and_frame(scene, tmp_path):
    _, sim, crop = scene
    run_prefit(crop.out_dir, tmp_path / "prefit", plot=False)
    table = pd.read_csv(tmp_path / "prefit" / "prefit.csv")
    assert list(table.columns[:2]) == ["particle", "frame"]
    assert len(table) == len(crop.frames) and (table["status"] == "ok").all()
    mapping = _track_to_truth(crop.frames, sim.truth)
    truth = sim.truth.assign(particle=sim.truth["particle"].map(
        {t: p for p, t in mapping.items()}))
    both = table.merge(truth, on=["particle", "frame"], suffixes=("", "_true"))
    assert len(both) == len(table)
    assert np.abs(both["x_um"] - both["x_um_true"]).max() < 0.03
    assert np.abs(both["y_um"] - both["y_um_true"]).max() < 0.03
    radius = both.groupby("particle")["radius_um"].median()
    assert radius[mapping_inverse(mapping, 0)] == pytest.approx(0.5, abs=0.03)
    assert radius[mapping_inverse(mapping, 2)] == pytest.approx(0.6, abs=0.05)


def mapping_inverse(mapping: dict[int, int], truth_id: int) -> int:
    return next(p for p, t in mapping.items() if t == truth_id)


def test_one_track_kept_with_particle(scene, inst, tmp_path):
    _, sim, crop = scene
    entering = mapping_inverse(_track_to_truth(crop.frames, sim.truth), 2)
    one = run_crop(sim.movie, sim.background, inst, tmp_path / "one",
                   CropConfig(size=SIZE, plot=False, particle=entering))
    # one track: a row per movie frame, as the single-particle modes give
    assert one.frames["particle"].eq(0).all() and len(one.frames) == N
    assert (one.frames["status"].iloc[:ENTERS] == "no_particle").all()
    assert (one.frames["status"].iloc[ENTERS:] == "ok").all()
    with pytest.raises(CropError, match=r"--particle 7: no such track \(tracks found: 0, 1, 2\)"):
        run_crop(sim.movie, sim.background, inst, tmp_path / "bad",
                 CropConfig(size=SIZE, plot=False, particle=7))
    assert not (tmp_path / "bad" / "crops.csv").exists()


def test_repeated_particle_frame_rows_are_refused(scene, tmp_path):
    _, _, crop = scene
    folder = tmp_path / "edited"
    shutil.copytree(crop.out_dir, folder)
    table = pd.read_csv(folder / "crops.csv")
    table.loc[3, ["particle", "frame"]] = table.loc[4, ["particle", "frame"]].to_numpy()
    table.to_csv(folder / "crops.csv", index=False)
    with pytest.raises(CropSetError, match=r"repeated \(particle, frame\) rows \(particle "):
        run_prefit(folder, tmp_path / "prefit", plot=False)
    assert not (tmp_path / "prefit" / "prefit.csv").exists()


def test_a_movie_without_holograms_says_so(inst, tmp_path):
    rng = np.random.default_rng(2)
    movie = rng.poisson(120.0, (6, 96, 96)).astype(np.uint8)
    tifffile.imwrite(tmp_path / "m.tif", movie, photometric="minisblack")
    tifffile.imwrite(tmp_path / "bg.tif", np.full((96, 96), 120, np.uint8),
                     photometric="minisblack")
    res = run_crop(tmp_path / "m.tif", tmp_path / "bg.tif", inst, tmp_path / "o",
                   CropConfig(size=48, plot=False))
    assert (res.frames["status"] == "no_particle").all()
    assert any("no hologram found in any frame" in w for w in res.notes)


def _detections(centres_by_frame):
    import json

    return {k: {"status": "ok", "n_found": len(c),
                "candidates": json.dumps([[x, y, 20.0, 0.8, 0.9, "symmetry"] for x, y in c])}
            for k, c in enumerate(centres_by_frame)}


def test_overlap_is_marked_closer_than_half_a_crop():
    """Two tracks approach each other: rows closer than size/2 are marked overlap and name
    the neighbour; a third, short track is reported and left out."""
    frames = [[(20.0, 50.0), (80.0 - 2 * k, 50.0)] for k in range(12)]
    frames[5].append((150.0, 150.0))  # a one-frame false detection
    plan = link_detections(_detections(frames), 12, 0.1, LinkSettings(min_track_length=4), 64)
    assert sorted(plan.spans) == [0, 1]
    assert "1 track(s) left out" in plan.warnings[0]
    for k in (0, 11):
        dist = 60.0 - 2 * k
        for p, det in track_rows(plan, k, 64):
            assert det["neighbour"] == 1 - p
            assert det["neighbour_px"] == pytest.approx(dist)
            assert det["overlap"] == (dist < 32)


@pytest.mark.slow
def test_the_fit_combines_the_tracks(scene, tmp_path):
    from holofit.fit.config import FitConfig
    from holofit.fit.stage import run_fit

    _, sim, crop = scene
    run_prefit(crop.out_dir, tmp_path / "prefit", plot=False)
    cfg = load_particle(resolve_config("sphere_ps_1um", "particles"))
    run = run_fit(crop.out_dir, tmp_path / "prefit", None, tmp_path / "fit",
                  FitConfig(cfg, plot=False))
    fit = pd.read_csv(run.final)
    assert list(fit.columns[:2]) == ["particle", "frame"] and len(fit) == len(crop.frames)
    mapping = _track_to_truth(crop.frames, sim.truth)
    truth = sim.truth.assign(particle=sim.truth["particle"].map({t: p for p, t in mapping.items()}))
    both = fit.merge(truth, on=["particle", "frame"], suffixes=("", "_true"))
    rms = np.sqrt(
        (
            (both[["x_um", "y_um"]].to_numpy() - both[["x_um_true", "y_um_true"]].to_numpy()) ** 2
        ).mean()
    )
    assert rms < 0.01  # 10 nm
    assert not list((tmp_path / "fit").glob("particle_*"))  # a track is keys, not a folder


def test_failed_fits_of_overlapping_frames_become_overlap():
    from holofit.fit.overlaps import mark_overlap

    fit = pd.DataFrame(
        {
            "particle": [0, 0, 0, 1],
            "frame": [1, 2, 3, 2],
            "status": ["poor_fit", "ok", "poor_fit", "failed"],
            "message": ["far above the noise", "", "x", ""],
        }
    )
    overlaps = pd.DataFrame(
        {
            "particle": [0, 0, 1],
            "frame": [1, 2, 2],
            "neighbour": [1, 1, 0],
            "neighbour_px": [20.0, 18.0, 18.0],
        }
    )
    out = mark_overlap(fit, overlaps)
    # overlapping and failing: overlap; overlapping and ok: ok; failing alone: unchanged
    assert out["status"].tolist() == ["overlap", "ok", "poor_fit", "overlap"]
    assert out["message"][0] == (
        "track 1's hologram overlaps (20 px away); fit poor_fit: far above the noise"
    )


def test_fringes_of_a_strong_hologram_are_not_a_track():
    """A steady weak 'centre' 20 px from a hologram three times as strong (its rings cut by
    the frame edge) is left out and reported; a weak particle far away is kept."""
    import json

    det = {}
    for k in range(12):
        found = [
            [50.0 + 0.1 * k, 50.0, 300.0, 0.9, 0.99, "symmetry"],
            [70.0, 50.0 + 0.05 * k, 100.0, 0.5, 0.9, "symmetry"],
            [200.0 - 0.1 * k, 150.0, 90.0, 0.8, 0.95, "symmetry"],
        ]
        det[k] = {"status": "ok", "n_found": 3, "candidates": json.dumps(found)}
    plan = link_detections(det, 12, 0.1, LinkSettings(min_track_length=4), 48)
    assert sorted(plan.spans) == [0, 1]
    assert plan.linked.groupby("particle")["x_px"].median().round().tolist() == [51.0, 199.0]
    assert any("fringes of a stronger hologram" in w and "(70, 50) px" in w for w in plan.warnings)


def test_run_fit_on_several_tracks_is_what_holofit_fit_runs(scene, tmp_path):
    """The public ``holofit.run_fit`` on the crop stage's own output of three tracks gives
    the very table ``holofit fit`` writes; every row keyed by (particle, frame), no per-track
    folder."""
    from click.testing import CliRunner

    import holofit
    from holofit.cli import main

    _, _, crop = scene
    run_prefit(crop.out_dir, tmp_path / "prefit", plot=False)
    cfg = load_particle(resolve_config("sphere_ps_1um", "particles"))
    config = holofit.FitConfig(cfg, initial_frames=2, frames=(6, 7, 8), plot=False)
    run = holofit.run_fit(
        crop.out_dir,
        tmp_path / "prefit",
        None,
        tmp_path / "api",
        config,
        batch=holofit.BatchSettings(workers=0, progress=False),
    )
    res = CliRunner().invoke(
        main,
        [
            "fit",
            str(crop.out_dir),
            "--prefit",
            str(tmp_path / "prefit"),
            "-p",
            "sphere_ps_1um",
            "-o",
            str(tmp_path / "cli"),
            "--initial-frames",
            "2",
            "--frames",
            "6:9",
            "--no-plot",
            "-j",
            "0",
        ],
    )
    assert res.exit_code == 0, res.output
    api = pd.read_csv(run.final).drop(columns="fit_time_s")
    cli = pd.read_csv(tmp_path / "cli" / "fit.csv").drop(columns="fit_time_s")
    pd.testing.assert_frame_equal(api, cli)
    assert sorted(api["particle"].unique()) == [0, 1, 2] and len(api) == 9
    assert not [
        p for p in (tmp_path / "api").iterdir() if p.is_dir() and p.name.startswith("particle")
    ]


def test_sparse_detections_strung_by_the_memory_are_not_a_track():
    from holofit.crop.tracks import LinkSettings, link_tracks

    rows = [(f, 100.0, 100.0) for f in range(60)]  # a particle, every frame
    rows += [(f, 135.0, 100.0) for f in range(10, 43, 3)]  # a fringe: 11 of 33 frames
    table = pd.DataFrame(rows, columns=["frame", "x_px", "y_px"])
    result = link_tracks(table, 0.1, LinkSettings(memory=10))
    assert len(result.particles) == 1
    dropped = result.summary[~result.summary["kept"].astype(bool)]
    assert dropped["reason"].str.contains("detected in 11 of the 31 frames").all()
    assert (
        len(link_tracks(table, 0.1, LinkSettings(memory=10, min_detected_fraction=0.0)).particles)
        == 2
    )
