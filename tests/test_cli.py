"""Every stage has a subcommand with --help."""

import numpy as np
import pytest
from click.testing import CliRunner

from holofit.cli import main


@pytest.mark.parametrize(
    "stage", ["crop", "prefit", "library", "fit", "analyze", "simulate", "demo"]
)
def test_help(stage):
    res = CliRunner().invoke(main, [stage, "--help"])
    assert res.exit_code == 0 and "Usage" in res.output


def test_simulate_hologram_of_a_rod_and_a_janus_particle(tmp_path):
    import tifffile

    from tests.conftest import CONFIGS

    for name, orient in (("rod_paper", "30,60,0"), ("janus_paper", "0,120,0")):
        out = tmp_path / name
        res = CliRunner().invoke(main, [
            "simulate", "hologram", "-p", str(CONFIGS / "particles" / f"{name}.toml"),
            "--position", "5,5,8", "--orientation", orient, "--shape", "96,96", "--no-noise",
            "-o", str(out)])
        assert res.exit_code == 0, res.output
        frame = tifffile.imread(out / "movie.tif").astype(float)
        background = tifffile.imread(out / "background.tif")[0].astype(float)
        ratio = frame / background
        assert ratio.std() > 0.02  # a hologram, not a blank frame
        # the pattern is centred where the particle is (5 um / 0.106 um ~ pixel 47)
        w = (ratio - 1) ** 2
        i, j = np.indices(ratio.shape)
        assert abs(np.sum(w * i) / w.sum() - 47) < 6 and abs(np.sum(w * j) / w.sum() - 47) < 6


@pytest.mark.parametrize("body", [
    'model = "spheroid"\na_um = 0.3\nc_um = 0.5\nindex = 1.5',
    'model = "ellipsoid"\nax_um = 0.3\nay_um = 0.4\naz_um = 0.5\nindex = 1.5',
    'model = "cylinder"\nradius_um = 0.3\nhalf_length_um = 0.5\nindex = 1.5',
    'model = "dimer"\nradius1_um = 0.3\nradius2_um = 0.3\ngap_um = 0.0\nindex1 = 1.5\n'
    'index2 = 1.5',
    'model = "voxels"\npath = "{geom}"\ndipole_size_um = 0.024\nindices = [1.59, 2.7]\n'
    'centre_um = [0.0, 0.0, -0.024]',
    'model = "coated_sphere"\nradius_um = 0.3\nshell_thickness_um = 0.05\nindex_core = 1.5\n'
    'index_shell = 2.0',
    'model = "cluster"\nradii_um = [0.3, 0.25]\nindices = [1.5, 1.6]\n'
    'positions_um = [[0, 0, -0.3], [0.1, 0.0, 0.3]]',
], ids=["spheroid", "ellipsoid", "cylinder", "dimer", "voxels", "coated sphere", "cluster"])
def test_simulate_hologram_of_every_model(tmp_path, body):
    import tifffile

    from tests.conftest import DATA

    geom = DATA / "adda" / "d_janus_o0_0_0" / "janus_d0.024.geom"
    cfg = tmp_path / "particle.toml"
    cfg.write_text("[particle]\n" + body.format(geom=geom) + "\n[dda]\ndipole_size_um = 0.05\n"
                   if "voxels" not in body else "[particle]\n" + body.format(geom=geom) + "\n")
    out = tmp_path / "out"
    res = CliRunner().invoke(main, ["simulate", "hologram", "-p", str(cfg), "--position",
                                    "3,3,6", "--orientation", "20,50,0", "--shape", "56,56",
                                    "--no-noise", "-o", str(out)])
    assert res.exit_code == 0, res.output
    frame = tifffile.imread(out / "movie.tif").astype(float)
    background = tifffile.imread(out / "background.tif")[0].astype(float)
    assert (frame / background).std() > 0.01
