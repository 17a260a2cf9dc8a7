"""A foreseeable failure is one line, `holofit <stage>: error: <message>`, exit status 1.

Checked through the real command line (click's runner, and one real process for what reaches
the terminal): a missing movie, a failing ADDA (tests/stubs/fake_adda.py in its failure modes),
a misspelled config key, a particle in the focal plane; ``--debug`` and ``HOLOFIT_DEBUG=1``
give the traceback back; a bug keeps its traceback; third-party log lines follow holofit's own
message.
"""

from __future__ import annotations

import logging
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from holofit.cli import main
from holofit.config import load_instrument
from holofit.config_schema import ConfigError
from holofit.crop import CropError
from holofit.dda import adda as ae
from tests.test_adda_stub import make_stub

ROOT = Path(__file__).resolve().parents[1]
DEBUG = "HOLOFIT_DEBUG"


def _invoke(args, **kw):
    return CliRunner().invoke(main, [str(a) for a in args], **kw)


@pytest.fixture(autouse=True)
def _no_debug(monkeypatch):
    monkeypatch.delenv(DEBUG, raising=False)


def test_missing_input_is_one_line(tmp_path):
    res = _invoke(["crop", tmp_path / "nothere.tif", "-b", tmp_path / "bg.tif", "-i",
                   "paper_60x_water", "-o", tmp_path / "o"])  # fmt: skip
    assert res.exit_code == 1
    movie = tmp_path / "nothere.tif"
    assert res.stderr == f"holofit crop: error: {movie}: no such file or folder\n"
    assert isinstance(res.exception, SystemExit)


@pytest.mark.parametrize("how", ["--debug", "env"])
def test_debug_shows_the_traceback(tmp_path, monkeypatch, how):
    args = ["crop", tmp_path / "nothere.tif", "-b", tmp_path / "bg.tif", "-i",
            "paper_60x_water", "-o", tmp_path / "o"]  # fmt: skip
    if how == "env":
        monkeypatch.setenv(DEBUG, "1")
    else:
        args = ["--debug", *args]
    res = _invoke(args)
    assert isinstance(res.exception, CropError)
    assert "nothere.tif" in str(res.exception)


def test_a_bug_keeps_its_traceback(tmp_path, monkeypatch):
    crop_cli = sys.modules["holofit.cli.crop"]

    def broken(*args, **kw):
        return 1 / 0

    monkeypatch.setattr(crop_cli, "run_crop", broken)
    res = _invoke(["crop", tmp_path / "m.tif", "--normalized", "-i", "paper_60x_water", "-o",
                   tmp_path / "o"])  # fmt: skip
    assert isinstance(res.exception, ZeroDivisionError)


def test_third_party_log_lines_come_after_holofits_message(tmp_path, monkeypatch):
    crop_cli = sys.modules["holofit.cli.crop"]

    def fails(*args, **kw):
        logging.getLogger("tifffile").warning("<TiffPages @8> invalid page offset 21128")
        raise CropError("movie.tif: every frame failed")

    monkeypatch.setattr(crop_cli, "run_crop", fails)
    res = _invoke(["crop", tmp_path / "m.tif", "--normalized", "-i", "paper_60x_water", "-o",
                   tmp_path / "o"])  # fmt: skip
    assert res.exit_code == 1
    assert res.stderr.splitlines() == [
        "holofit crop: error: movie.tif: every frame failed",
        "  (tifffile: <TiffPages @8> invalid page offset 21128)",
    ]


def test_truncated_movie_in_a_real_terminal(tmp_path):
    """What a user sees: holofit's warning and error rows, no tifffile line, exit status 0."""
    from PIL import Image

    rng = np.random.default_rng(0)
    frames = [Image.fromarray(rng.integers(90, 110, (64, 64), dtype=np.uint8)) for _ in range(10)]
    frames[0].save(tmp_path / "movie.tif", save_all=True, append_images=frames[1:])
    data = (tmp_path / "movie.tif").read_bytes()
    (tmp_path / "movie.tif").write_bytes(data[: len(data) // 2])
    frames[0].save(tmp_path / "bg.tif")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    env.pop(DEBUG, None)
    done = subprocess.run(
        [sys.executable, "-m", "holofit.cli", "crop", str(tmp_path / "movie.tif"), "-b",
         str(tmp_path / "bg.tif"), "-i", "paper_60x_water", "-o", str(tmp_path / "o"),
         "--size", "32", "--no-plot"],
        capture_output=True, text=True, env=env, timeout=120,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    err = done.stderr.splitlines()
    assert err[0] == (
        f"holofit crop: warning: {tmp_path / 'movie.tif'}: the file is truncated "
        f"({len(data) // 2} bytes): frame 5 and any frames after it (the file does not say how "
        "many it had) cannot be read"
    )
    assert err[1].startswith(f"  error: {tmp_path / 'movie.tif'}: frame 5 cannot be read: the "
                             "file is truncated: its directory, at byte")
    assert "tifffile" not in done.stderr and "Traceback" not in done.stderr
    assert "(6 frames: 5 no_particle, 1 error)" in done.stdout


@pytest.fixture
def failing_adda(tmp_path, monkeypatch):
    monkeypatch.setenv(ae.ADDA_ENV_VAR, str(make_stub(tmp_path / "bin")))
    monkeypatch.delenv("FAKE_ADDA_CALLS", raising=False)
    return tmp_path


@pytest.mark.parametrize(
    "mode,said",
    [
        ("exit", "ADDA exited with status 3: stand-in crashed: out of memory"),
        ("error", "ADDA reported an error: ERROR: (../make_particle.c:1061) Failed to open file "
                  "'shape.dat'"),
        ("noampl", "ADDA ran (exit status 0) but its output is unusable: out/ampl_scatgrid: ADDA "
                   "wrote no ampl_scatgrid; ADDA printed nothing"),
    ],
)
def test_failing_adda_shows_its_message_and_command(failing_adda, monkeypatch, mode, said):
    monkeypatch.setenv("FAKE_ADDA_MODE", mode)
    out = failing_adda / "rod"
    res = _invoke(["simulate", "hologram", "-p", "rod_paper", "--engine", "adda", "--position",
                   "3,3,10", "--shape", "24,24", "--no-noise", "-o", out])  # fmt: skip
    assert res.exit_code == 1
    lines = [ln for ln in res.stderr.splitlines() if "warning:" not in ln]
    assert lines[0] == f"holofit simulate hologram: error: {said}"
    assert lines[1].startswith(f"command: {failing_adda / 'bin' / 'adda'} -shape read shape.dat")
    assert "Traceback" not in res.output
    assert not out.exists() or not (out / "movie.tif").exists()


def test_misspelled_instrument_key_is_named_with_the_right_one(tmp_path):
    path = tmp_path / "scope.toml"
    path.write_text(
        "[instrument]\nname = 'x'\nwavelength_um = 0.66\nmedium_index = 1.33\n"
        "pixel_size_mu = 0.1\npolarization_deg = 0\nbit_depth = 8\n"
    )
    with pytest.raises(ConfigError) as info:
        load_instrument(path)
    assert str(info.value).startswith(
        f"{path}: [instrument] has unknown key 'pixel_size_mu' (did you mean 'pixel_size_um', "
        "the pixel pitch in the sample plane in um?); allowed keys: name, description, "
        "wavelength_um,"
    )
    assert "missing" not in str(info.value)  # the typo explains the missing key
    res = _invoke(["crop", tmp_path / "m.tif", "--normalized", "-i", path, "-o", tmp_path / "o"])
    assert res.exit_code == 1 and "did you mean 'pixel_size_um'" in res.output
    assert res.output.startswith("holofit crop: error: ") and "Usage:" not in res.output


def test_every_missing_and_unknown_key_at_once(tmp_path):
    path = tmp_path / "scope.toml"
    path.write_text("[instrument]\nname = 'x'\nwavelength = 0.66\ncolour = 'red'\n")
    with pytest.raises(ConfigError) as info:
        load_instrument(path)
    message = str(info.value)
    assert "unknown keys 'colour', 'wavelength' (did you mean 'wavelength_um'" in message
    assert ("is missing keys 'medium_index' (the refractive index of the medium), "
            "'pixel_size_um'") in message
    assert "'bit_depth' (the camera bit depth)" in message
    assert "missing keys 'wavelength_um'" not in message


def test_every_documented_instrument_key_is_a_real_one():
    """The configuration page's full instrument example loads, and its key table lists every
    key."""
    import re
    import tomllib

    from holofit.config import INSTRUMENT_SPECS

    page = (ROOT / "docs" / "configuration.md").read_text()
    section = page[page.index("## Instrument files"):page.index("## Particle files")]
    example = re.search(r"```toml\n(\[instrument\].*?)```", section, re.S).group(1)
    assert set(tomllib.loads(example)["instrument"]) == set(INSTRUMENT_SPECS)
    listed = set(re.findall(r"^\| `(\w+)` \|", section, re.M))
    assert set(INSTRUMENT_SPECS) <= listed


def test_particle_in_the_focal_plane_names_the_option_and_frame(tmp_path):
    # an instrument without an objective NA: the ideal model, which needs z > radius
    ideal = tmp_path / "ideal.toml"
    ideal.write_text('[instrument]\nname = "ideal"\nwavelength_um = 0.66\nmedium_index = 1.33\n'
                     'pixel_size_um = 0.1\npolarization_deg = 0.0\nbit_depth = 8\n')
    out = tmp_path / "sim"
    res = _invoke(["simulate", "sphere", "-i", ideal, "--position", "12,12,10",
                   "--position", "12,12,0", "--shape", "32,32", "-o", out])  # fmt: skip
    assert res.exit_code == 2
    text = " ".join(res.output.split())
    assert ("Invalid value for --position: frame 1: the particle centred at (12, 12, 0) um is "
            "cut by the focal plane") in text
    assert "bounding radius, 0.5 um" in text and "(--position 12,12,0)" in text
    assert "numerical_aperture" in text
    assert not out.exists()
    table = tmp_path / "traj.csv"
    table.write_text("x_um,y_um,z_um\n1,1,5\n1,1,-4\n")
    res = _invoke(["simulate", "hologram", "-p", "sphere_ps_1um", "-i", ideal,
                   "--trajectory", table, "--shape", "32,32", "-o", out])  # fmt: skip
    assert res.exit_code == 2
    assert "row 2 of the table: frame 1" in res.output and "below the focal plane" in res.output
    # through the objective (the default instrument, NA 1.40) every height is imaged
    res = _invoke(["simulate", "hologram", "-p", "sphere_ps_1um", "--trajectory", table,
                   "--shape", "32,32", "-o", out, "--no-noise"])  # fmt: skip
    assert res.exit_code == 0, res.output


@pytest.mark.parametrize(
    "args,option",
    [
        (["--frames", "1"], "--n-frames' / '--frames"),
        (["--frame-rate", "0"], "--frame-rate"),
        (["--d-r", "-1"], "--d-r"),
        (["--flip-fraction", "1"], "--flip-fraction"),
        (["--seed", "-2"], "--seed"),
    ],
)
def test_trajectory_options_are_named(tmp_path, args, option):
    base = ["simulate", "trajectory", "--d-t", "0.3", "--d-r", "0.3", "-o", tmp_path / "t"]
    res = _invoke([*base, *args])
    assert res.exit_code == 2 and f"Invalid value for '{option}'" in res.output


def test_analyze_failures_read_like_every_stage(tmp_path):
    bad = tmp_path / "three.csv"
    bad.write_text("frame,x_um\n0,1.0\n")
    res = _invoke(["analyze", bad, "-m", "sphere", "-o", tmp_path / "a"])
    assert res.exit_code == 1
    lines = [ln for ln in res.output.splitlines() if ln.strip()]
    assert lines[0].startswith("holofit analyze: error: ") and str(bad) in lines[0], res.output
    assert res.output.count(str(bad)) == 1, res.output  # the file named once
