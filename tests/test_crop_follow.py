"""Issue 24, item 5: single-particle mode (``--follow strongest``) with a second particle in
view no longer swaps between them without a word: the frames off the main track are marked
``off_track`` (not fitted) and the crop says so."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import tifffile
from click.testing import CliRunner

from holofit.cli import main
from holofit.config import load_instrument, load_particle, resolve_config
from holofit.crop import CropConfig, run_crop
from holofit.crop.follow import off_track
from holofit.simulate.holograms import Exposure, simulate_movie

#: frames in which the second, stronger hologram is in view
B_FRAMES = range(10, 15)


def test_tracks_split_at_jumps_and_rejoin():
    x = np.array([10, 11, 12, 80, 81, 12, 13, np.nan, 14, 15.0])
    y = np.array([10, 10, 11, 80, 80, 11, 12, np.nan, 12, 13.0])
    t = off_track(x, y, 12.0)
    assert t.jumps == [3, 5]
    assert t.label.tolist() == [0, 0, 0, 1, 1, 0, 0, -1, 0, 0] and t.n_tracks == 2
    # alternating every frame: the more frequent one is the main track
    x = np.array([10, 80, 10, 80, 10.0])
    assert off_track(x, x, 12.0).off.tolist() == [False, True, False, True, False]
    # a particle that moves steadily, never by a jump, is one track however far it goes
    x = np.arange(0, 200, 10.0)
    t = off_track(x, x * 0, 12.0)
    assert not t.off.any() and t.jumps == []


@pytest.fixture(scope="module")
def two_particles(tmp_path_factory):
    """30 frames of a 1-um sphere diffusing near (33, 33) px; in frames 10-14 a second one,
    nearer the focus (its hologram the strongest), sits at (85, 85) px. Noise-free holograms
    of each are simulated (Lorenz-Mie) and added (their scattered fields' interference with
    the incident wave; the cross term between the two is negligible so far apart), then
    Poisson noise and 8-bit counts."""
    out = tmp_path_factory.mktemp("two")
    inst = load_instrument(resolve_config("paper_100x_oil", "instruments"))
    sphere = load_particle(resolve_config("sphere_ps_1um", "particles"))
    rng = np.random.default_rng(0)
    n = 30
    walk = 0.02 * np.cumsum(rng.normal(size=(n, 2)), axis=0)
    pa = np.column_stack([3.5 + walk, np.full(n, 12.0)])
    pb = np.tile([9.0, 9.0, 8.0], (n, 1))
    kw = {"exposure": Exposure(noise=False, n_background=1), "keep_frames": True}
    sa = simulate_movie(sphere.model, inst, pa, (128, 128), theory=sphere.theory(),
                        out_dir=out / "a", **kw)
    sb = simulate_movie(sphere.model, inst, pb, (128, 128), theory=sphere.theory(), **kw)
    bg = tifffile.imread(sa.background).astype(float)
    frames = np.array(sa.frames, dtype=float)
    for k in B_FRAMES:
        frames[k] += np.asarray(sb.frames[k], dtype=float) - bg
    movie = np.clip(rng.poisson(np.clip(frames, 0, None)), 0, 255).astype(np.uint8)
    tifffile.imwrite(out / "movie.tif", movie, photometric="minisblack")
    tifffile.imwrite(out / "bg.tif", np.round(bg).astype(np.uint8), photometric="minisblack")
    return out, inst


def test_the_other_particles_frames_are_off_track_and_said(two_particles, tmp_path):
    out, inst = two_particles
    result = run_crop(out / "movie.tif", out / "bg.tif", inst, tmp_path / "crop",
                      CropConfig(size=48, plot=False, follow="strongest"))
    status = result.frames.set_index("frame")["status"]
    # the strongest hologram is the second particle's while it is in view: before, these
    # five frames were `ok` at (85, 85) px, and a fit would have followed the other particle
    assert (status.loc[list(B_FRAMES)] == "off_track").all()
    assert (status.drop(list(B_FRAMES)) == "ok").all()
    assert result.counts["off_track"] == 5
    (warning,) = result.warnings
    assert "jumped by more than 12 px" in warning and "frame(s) 10, 15" in warning
    table = pd.read_csv(tmp_path / "crop" / "crops.csv").set_index("frame")
    x0, y0 = table.loc[0, "x_px"], table.loc[0, "y_px"]
    assert abs(x0 - 33) < 3 and abs(y0 - 33) < 3  # the first particle's place
    assert f"--follow nearest --start {x0:.0f},{y0:.0f}" in warning
    assert "off the movie's main track" in table.loc[12, "message"]


def test_the_crop_command_warns(two_particles, tmp_path):
    out, _ = two_particles
    res = CliRunner().invoke(main, ["crop", str(out / "movie.tif"), "-b", str(out / "bg.tif"),
                                    "-i", "paper_100x_oil", "-o", str(tmp_path / "c"),
                                    "--size", "48", "--no-plot", "--follow", "strongest"])
    assert res.exit_code == 0, res.output
    assert "25 ok" in res.stdout and "5 off_track" in res.stdout
    assert "holofit crop: warning: the strongest hologram jumped" in res.stderr
    # following one particle from its start point: no jump, nothing off track
    res = CliRunner().invoke(main, ["crop", str(out / "movie.tif"), "-b", str(out / "bg.tif"),
                                    "-i", "paper_100x_oil", "-o", str(tmp_path / "n"),
                                    "--size", "48", "--no-plot", "--follow", "nearest",
                                    "--start", "33,33"])
    assert res.exit_code == 0 and "30 ok" in res.stdout and "warning" not in res.stderr
