"""``holofit init``: the run folder it writes, the commands its Makefile would run (``make -n``,
no stage runs), and bad input, each refused with one line before anything is written."""

from __future__ import annotations

import numpy as np
import pytest
import tifffile
from click.testing import CliRunner

from holofit.cli import main
from holofit.config import load_instrument, load_particle, resolve_config
from holofit.runfolder import RunFolderError, RunInputs, init_run
from tests.runfolder_helpers import holofit_command, names, needs_make, run_make, stages_run


@pytest.fixture
def inputs(tmp_path):
    """A 3-frame 8-bit movie, its background and a dark frame (only read, never fitted; as
    large as the default crop)."""
    rng = np.random.default_rng(0)
    data = tmp_path / "data"
    data.mkdir()
    paths = {}
    for name, frames in (("movie", 3), ("bg", 2), ("dark", 1)):
        paths[name] = data / f"{name}.tif"
        tifffile.imwrite(paths[name], rng.integers(10, 200, (frames, 144, 144), dtype=np.uint8),
                         photometric="minisblack")
    return paths


def _init(tmp_path, inputs, *extra, run="run01", particle="rod_paper"):
    args = ["init", str(tmp_path / run), "--movie", str(inputs["movie"]), "-b", str(inputs["bg"]),
            "-i", "paper_60x_water", "-p", particle, *map(str, extra)]
    return CliRunner().invoke(main, args)


def test_init_writes_a_self_describing_folder(tmp_path, inputs):
    res = _init(tmp_path, inputs)
    assert res.exit_code == 0, res.output
    run = tmp_path / "run01"
    for name in ("Makefile", "README.md", "instrument.toml", "particle.toml"):
        assert (run / name).is_file(), name
    # the copies read as the configs they were made from
    for kind, load, name in (("instruments", load_instrument, "paper_60x_water"),
                             ("particles", load_particle, "rod_paper")):
        original = load(resolve_config(name, kind)).as_dict()
        copy = load(run / f"{kind[:-1]}.toml").as_dict()
        assert {k: v for k, v in copy.items() if k != "path"} == {
            k: v for k, v in original.items() if k != "path"}
        assert str(resolve_config(name, kind).resolve()) in (run / f"{kind[:-1]}.toml").read_text()
    readme = (run / "README.md").read_text()
    assert str(inputs["movie"]) in readme and "make library" in readme


@needs_make
def test_the_makefile_chains_the_stages_with_the_run_folder_inputs(tmp_path, inputs):
    assert _init(tmp_path, inputs).exit_code == 0
    run = tmp_path / "run01"
    proc = run_make(run, "-n")
    assert proc.returncode == 0, proc.stdout
    ran = stages_run(proc.stdout, run)
    assert names(ran) == ["crop", "prefit", "library", "fit initial", "fit final", "analyze"]
    opts = dict(ran)
    assert opts["crop"].split() == [str(inputs["movie"]), "-b", str(inputs["bg"]), "-i",
                                    "instrument.toml", "-o", "crop"]
    assert opts["library"].split()[:6] == ["crop", "--prefit", "prefit", "-p", "particle.toml",
                                           "-o"]
    assert "--library library -p particle.toml" in opts["fit initial"]
    # the analysis reads each track's model from the fit table, as in a population
    assert opts["analyze"].split() == ["fit/fit.csv", "-o", "analysis", "--temperature-c", "21"]
    assert not any("--overwrite" in o for o in opts.values())
    # how the stages run: workers, a Dask scheduler, the holofit command
    proc = run_make(run, "-n", "JOBS=3", "SCHEDULER=tcp://10.0.0.5:8786", "HOLOFIT=myholofit")
    ran = stages_run(proc.stdout, run, command="myholofit")
    assert len(ran) == 6
    for stage, o in ran:
        if stage.split()[0] in ("prefit", "library", "fit"):
            assert "-j 3 --scheduler tcp://10.0.0.5:8786" in o, (stage, o)
        elif stage == "crop":  # JOBS reaches every stage that runs frames in parallel
            assert o.split()[-2:] == ["-j", "3"] and "--scheduler" not in o, (stage, o)
        else:
            assert "-j" not in o.split() and "--scheduler" not in o, (stage, o)


@needs_make
def test_a_sphere_has_no_library_stage_and_options_reach_their_stage(tmp_path, inputs):
    res = _init(tmp_path, inputs, "--dark", inputs["dark"], "--engine", "mie",
                "--temperature-c", 25, "--fit-opts", "--initial-frames 50 --no-plot",
                "--crop-opts", "--size 20", particle="sphere_ps_1um")
    assert res.exit_code == 0, res.output
    run = tmp_path / "run01"
    ran = stages_run(run_make(run, "-n").stdout, run)
    assert names(ran) == ["crop", "prefit", "fit initial", "fit final", "analyze"]
    opts = dict(ran)
    assert f"--dark {inputs['dark']}" in opts["crop"] and opts["crop"].endswith("--size 20")
    for fit in ("fit initial", "fit final"):
        assert "--library" not in opts[fit]
        assert "--engine mie --initial-frames 50 --no-plot" in opts[fit]
    assert "--model" not in opts["analyze"] and "--temperature-c 25" in opts["analyze"]
    assert "library: skipped: a sphere" in run_make(run, "library").stdout
    # a model given to init is imposed on every track
    res = _init(tmp_path, inputs, "--model", "sphere", run="run02", particle="sphere_ps_1um")
    assert res.exit_code == 0, res.output
    forced = dict(stages_run(run_make(tmp_path / "run02", "-n").stdout, tmp_path / "run02"))
    assert "--model sphere --temperature-c 21" in forced["analyze"]
    assert "`--model sphere`" in (tmp_path / "run02" / "README.md").read_text()


@needs_make
def test_settings_records_change_only_when_the_settings_do(tmp_path, inputs):
    assert _init(tmp_path, inputs).exit_code == 0
    run = tmp_path / "run01"
    run_make(run, "-n")  # a dry run changes nothing
    assert not (run / "settings").exists()
    run_make(run, "settings")
    records = sorted((run / "settings").iterdir())
    assert [p.name for p in records] == ["analyze", "crop", "fit", "library", "prefit"]
    before = {p.name: p.stat().st_mtime_ns for p in records}
    run_make(run, "settings", "JOBS=4")  # how, not what: nothing recorded
    assert {p.name: p.stat().st_mtime_ns for p in records} == before
    run_make(run, "-n", "CROP_OPTS=--size 24 --start '3,4'")  # dry: still nothing
    assert {p.name: p.stat().st_mtime_ns for p in records} == before
    run_make(run, "settings", "CROP_OPTS=--size 24 --start '3,4'")
    after = {p.name: p.stat().st_mtime_ns for p in records}
    assert [k for k in after if after[k] != before[k]] == ["crop"]
    assert (run / "settings" / "crop").read_text().endswith("options --size 24 --start '3,4'\n")


def test_init_again_needs_force_and_keeps_unchanged_copies(tmp_path, inputs):
    assert _init(tmp_path, inputs).exit_code == 0
    run = tmp_path / "run01"
    res = _init(tmp_path, inputs)
    assert res.exit_code == 1
    assert res.stderr.startswith(f"holofit init: error: {run / 'Makefile'} exists")
    stamps = {n: (run / n).stat().st_mtime_ns for n in ("instrument.toml", "particle.toml")}
    assert _init(tmp_path, inputs, "--force").exit_code == 0
    # unchanged copies keep their time stamps: make reruns nothing because of them
    assert {n: (run / n).stat().st_mtime_ns for n in stamps} == stamps
    assert _init(tmp_path, inputs, "--force", particle="dimer_holopy2011").exit_code == 0
    assert (run / "particle.toml").stat().st_mtime_ns > stamps["particle.toml"]
    assert "model = \"dimer\"" in (run / "particle.toml").read_text()
    # a dimer of unequal spheres: the fit table does not decide its analysis, the Makefile does
    assert "\nMODEL         = rod\n" in (run / "Makefile").read_text()


@pytest.mark.parametrize("case", ["missing movie", "not a movie", "unknown instrument",
                                  "unknown particle", "no background", "space in path",
                                  "reserved option", "unknown option", "positional option",
                                  "no analysis model"])
def test_bad_input_is_one_line_and_writes_nothing(tmp_path, inputs, case):
    movie = str(inputs["movie"])
    args = ["init", str(tmp_path / "run"), "--movie", movie, "-b", str(inputs["bg"]),
            "-i", "paper_60x_water", "-p", "rod_paper"]
    code, message = 1, None
    if case == "missing movie":
        args[3] = str(tmp_path / "nothere.tif")
        message = f"holofit init: error: movie {tmp_path / 'nothere.tif'}: no such file or folder"
    elif case == "not a movie":
        (tmp_path / "notes.tif").write_text("not a TIFF")
        args[3] = str(tmp_path / "notes.tif")
        message = f"holofit init: error: movie: {tmp_path / 'notes.tif'}"
    elif case == "unknown instrument":
        args[7] = "paper_99x_water"
        message = "holofit init: error: paper_99x_water: no such instrument config"
    elif case == "unknown particle":
        args[9] = "rod_papr"
        message = "holofit init: error: rod_papr: no such particle config"
    elif case == "no background":
        del args[4:6]
        message = "holofit init: error: give the background of the raw movie"
    elif case == "space in path":
        spaced = tmp_path / "my data"
        spaced.mkdir()
        (spaced / "movie.tif").write_bytes(inputs["movie"].read_bytes())
        args[3] = str(spaced / "movie.tif")
        message = f"holofit init: error: movie {spaced / 'movie.tif'}: make cannot use a path " \
                  "with space in it"
    elif case == "reserved option":
        args += ["--fit-opts", "--no-plot --overwrite"]
        message = "holofit init: error: fit options '--no-plot --overwrite': --overwrite is " \
                  "set by the run folder's Makefile"
    elif case == "unknown option":
        args += ["--prefit-opts", "--fix-alfa 1"]
        code, message = 2, "No such option '--fix-alfa'"
    elif case == "positional option":
        args += ["--crop-opts", "other.tif --size 64"]
        code, message = 2, "options only"
    elif case == "no analysis model":
        particle = tmp_path / "ellipsoid.toml"
        particle.write_text('[particle]\nmodel = "ellipsoid"\nax_um = 0.5\nay_um = 0.4\n'
                            'az_um = 0.3\nindex = 1.5\n')
        args[9] = str(particle)
        message = "holofit init: error: which diffusion analysis suits a 'ellipsoid' particle?"
    res = CliRunner().invoke(main, args)
    assert res.exit_code == code, res.output
    if code == 1:
        assert res.stderr.startswith(message), res.stderr
        assert len(res.stderr.strip().splitlines()) == 1
        assert "Traceback" not in res.output
    else:
        assert message in res.stderr
    assert not (tmp_path / "run").exists()


def test_library_function_refuses_what_make_cannot_do(tmp_path, inputs):
    common = dict(instrument="paper_60x_water", particle="rod_paper")
    bg = [inputs["bg"]]
    with pytest.raises(RunFolderError, match=r"either dark frames .* or a dark level"):
        init_run(tmp_path / "r", RunInputs(inputs["movie"], bg, [inputs["dark"]], 3), **common)
    with pytest.raises(RunFolderError, match=r"normalised movie .* takes no background"):
        init_run(tmp_path / "r", RunInputs(inputs["movie"], bg, normalized=True), **common)
    with pytest.raises(RunFolderError, match="unknown stage"):
        init_run(tmp_path / "r", RunInputs(inputs["movie"], bg), options={"fitt": "--no-plot"},
                 **common)
    with pytest.raises(RunFolderError, match="analysis temperature_c"):
        init_run(tmp_path / "r", RunInputs(inputs["movie"], bg), temperature_c=294.0, **common)
    assert not (tmp_path / "r").exists()


@needs_make
def test_a_batch_makefile_runs_every_run_folder(tmp_path, inputs):
    for run in ("m01", "m02"):
        res = _init(tmp_path / "runs", inputs, "--batch-makefile", run=run)
        assert res.exit_code == 0, res.output
    parent = tmp_path / "runs"
    proc = run_make(parent, "-n", "TARGET=prefit", "JOBS=2")
    assert proc.returncode == 0, proc.stdout
    command = holofit_command(parent / "m01")
    lines = [line for line in proc.stdout.splitlines() if line.startswith(command)]
    # each folder, up to prefit, with the workers given at the top
    assert [line.split()[len(command.split())] for line in lines] == ["crop", "prefit"] * 2
    assert all(line.endswith("-j 2") for line in lines if " prefit " in line)
    # a Makefile that holofit did not write is left alone
    other = tmp_path / "other"
    other.mkdir()
    (other / "Makefile").write_text("all:\n\techo mine\n")
    res = _init(other, inputs, "--batch-makefile", run="m01")
    assert res.exit_code == 0 and "left as it is" in res.stderr
    assert (other / "Makefile").read_text() == "all:\n\techo mine\n"


def test_a_voxel_particle_brings_its_shape_file(tmp_path, inputs):
    from tests.conftest import DATA

    shapes = tmp_path / "configs" / "shapes"
    shapes.mkdir(parents=True)
    geom = DATA / "adda" / "d_janus_o0_0_0" / "janus_d0.024.geom"
    (shapes / "janus.geom").write_bytes(geom.read_bytes())
    cfg = tmp_path / "configs" / "janus_voxels.toml"
    cfg.write_text(
        '[particle]\nmodel = "voxels"\npath = "shapes/janus.geom"\n'
        "dipole_size_um = 0.024\nindices = [1.59, 2.7]\n"
    )
    with pytest.raises(RunFolderError, match="which diffusion analysis"):
        init_run(
            tmp_path / "run",
            RunInputs(inputs["movie"], backgrounds=[inputs["bg"]]),
            instrument="paper_100x_oil",
            particle=cfg,
        )
    made = init_run(
        tmp_path / "run",
        RunInputs(inputs["movie"], backgrounds=[inputs["bg"]]),
        instrument="paper_100x_oil",
        particle=cfg,
        model="janus",
    )
    assert (tmp_path / "run" / "shapes" / "janus.geom").read_bytes() == geom.read_bytes()
    copy = load_particle(made.particle).model.parameters()
    original = load_particle(cfg).model.parameters()
    assert copy.pop("path") == str(tmp_path / "run" / "shapes" / "janus.geom")  # the copy's
    original.pop("path")
    assert copy == original
    assert made.spec.anisotropic and made.spec.analysis_model == "janus"


@pytest.mark.parametrize(
    ("opts", "code", "message"),
    [
        # issue 24, item 6: each was accepted and failed only in make
        (
            (),
            1,
            "holofit init: error: the movie's frames (96 x 96 pixels) are smaller than the "
            "default crop (140 x 140): give --crop-opts '--size N' with N <= 96",
        ),
        (
            ("--crop-opts", "--size 120"),
            1,
            "holofit init: error: --crop-opts '--size 120': crop "
            "size 120 does not fit in frames of 96 x 96 pixels: "
            "give a smaller --size (at most 96)",
        ),
        (
            ("--crop-opts", "--size 64 --follow all"),
            2,
            "'all' is not one of 'strongest', 'nearest'",
        ),
        (("--crop-opts", "--size 64 --start 40,50"), 1, "--start X,Y needs --follow nearest"),
        (
            ("--crop-opts", "--size 64 --follow nearest --start 40,150"),
            1,
            "--start 40,150 lies outside the frames",
        ),
        (("--crop-opts", "--size=64 --follow nearest --start 40"), 1, "expected X,Y in pixels"),
        (
            ("--crop-opts", "--size 64", "--fit-opts", "--fix b_um,radius_um"),
            1,
            "cannot fix radius_um: a spherocylinder's fit parameters are",
        ),
        (
            ("--crop-opts", "--size 64", "--fit-opts", "--initial-frames 0"),
            2,
            "Invalid value for '--initial-frames'",
        ),
        (
            ("--crop-opts", "--size 64", "--prefit-opts", "--max-chi2-red lots"),
            2,
            "Invalid value for '--max-chi2-red'",
        ),
    ],
)
def test_stage_settings_that_cannot_work_are_refused_at_init(tmp_path, opts, code, message):
    """A 96 x 96 movie: the crop's size against its frames (the default 140 too), the follow
    mode and start point, the parameters --fix may name, option values of the right type."""
    movie, bg = tmp_path / "movie.tif", tmp_path / "bg.tif"
    rng = np.random.default_rng(1)
    for path, n in ((movie, 4), (bg, 1)):
        tifffile.imwrite(
            path, rng.integers(10, 200, (n, 96, 96), dtype=np.uint8), photometric="minisblack"
        )
    res = CliRunner().invoke(
        main,
        [
            "init",
            str(tmp_path / "run"),
            "--movie",
            str(movie),
            "-b",
            str(bg),
            "-i",
            "paper_60x_water",
            "-p",
            "rod_paper",
            *opts,
        ],
    )
    assert res.exit_code == code, res.output
    assert message in res.stderr, res.stderr
    assert "Traceback" not in res.output
    assert not (tmp_path / "run").exists()
    # the same settings that do work are accepted
    good = CliRunner().invoke(
        main,
        [
            "init",
            str(tmp_path / "ok"),
            "--movie",
            str(movie),
            "-b",
            str(bg),
            "-i",
            "paper_60x_water",
            "-p",
            "rod_paper",
            "--crop-opts",
            "--size 64 --follow nearest --start 40,50",
            "--fit-opts",
            "--fix b_um",
        ],
    )
    assert good.exit_code == 0, good.output


def test_init_says_what_the_fit_initial_pass_will_take(tmp_path, inputs):
    """Issue 24, item 14: the initial pass's default follows the movie's length, and init
    says what it will be (this movie: 3 frames)."""
    res = _init(tmp_path, inputs)
    assert res.exit_code == 0, res.output
    assert "the initial pass (every parameter free" in res.stderr
    assert "will take 3 of the movie's 3 frames" in res.stderr
    res = _init(tmp_path, inputs, "--fit-opts", "--initial-frames 2", run="run02")
    assert res.exit_code == 0 and "initial pass" not in res.stderr
    sphere = _init(tmp_path, inputs, run="run03", particle="sphere_ps_1um")
    assert sphere.exit_code == 0 and "initial pass" in sphere.stderr


@needs_make
def test_a_population_names_every_model_and_the_rod_is_the_primary(tmp_path, inputs):
    """``-p sphere_ps_1um -p rod_paper``: the non-spherical model is the run's primary
    (particle.toml: the library ranks its orientations), the sphere its alternative
    (particle_sphere.toml), and the fit is given both; a second non-spherical model is
    refused."""
    res = _init(tmp_path, inputs, "-p", "rod_paper", particle="sphere_ps_1um")
    assert res.exit_code == 0, res.output
    run = tmp_path / "run01"
    assert 'model = "spherocylinder"' in (run / "particle.toml").read_text()
    assert 'model = "sphere"' in (run / "particle_sphere.toml").read_text()
    ran = dict(stages_run(run_make(run, "-n").stdout, run))
    assert "library" in ran
    assert "-p particle.toml -p particle_sphere.toml" in ran["fit initial"]
    # no model forced on the analysis: each track gets the one of the model the fit gave it
    assert ran["analyze"].split() == ["fit/fit.csv", "-o", "analysis", "--temperature-c", "21"]
    assert "each track with the model of the particle" in (run / "README.md").read_text()
    # ... unless one is given (it was dropped in a population)
    res = _init(tmp_path, inputs, "-p", "rod_paper", "--model", "rod", run="run02",
                particle="sphere_ps_1um")
    assert res.exit_code == 0, res.output
    forced = dict(stages_run(run_make(tmp_path / "run02", "-n").stdout, tmp_path / "run02"))
    assert "--model rod --temperature-c 21" in forced["analyze"]
    twice = _init(tmp_path / "b", inputs, "-p", "janus_paper", particle="rod_paper")
    assert twice.exit_code == 1 and "second non-spherical model" in twice.output
