"""Option names mean one thing throughout, old spellings still work, every option is documented
(issue 24, item 9).

The truths: the same run under the old and the new spelling (identical outputs), the particle
models' own fit parameters (for ``fit --fix``), and the particle a fit sidecar records (for
``analyze`` without ``--model``).
"""

from __future__ import annotations

import json

import click
import pandas as pd
import pytest
from click.testing import CliRunner

from holofit.analysis.population import model_from_sidecar
from holofit.cli import COMMANDS, main
from holofit.config import load_particle
from holofit.holomodel.parameters import static_parameters
from tests.test_crop_cli import _movie


def _invoke(args):
    return CliRunner().invoke(main, [str(a) for a in args])


def _commands():
    for name in COMMANDS:
        command = main.get_command(None, name)
        if isinstance(command, click.Group):
            for sub in command.commands.values():
                yield f"{name} {sub.name}", sub
        else:
            yield name, command


def test_every_option_has_a_help_text():
    missing = [f"{name} {opt.opts[0]}" for name, command in _commands()
               for opt in command.params
               if isinstance(opt, click.Option) and not (opt.help or "").strip()]
    assert missing == []


def test_frames_is_a_range_everywhere_and_counts_are_n_frames():
    for name, command in _commands():
        for opt in command.params:
            if "--frames" in opt.opts and opt.opts[0] == "--frames":
                assert opt.metavar == "START:STOP", name
            if "--n-frames" in opt.opts:
                assert "--frames: the old name, deprecated" in opt.help, name


def test_old_and_new_spellings_give_the_same_run(tmp_path):
    new = _invoke(["simulate", "trajectory", "--n-frames", "5", "--d-t", "0.3", "--d-r", "0.3",
                   "-o", tmp_path / "new"])
    old = _invoke(["simulate", "trajectory", "--frames", "5", "--d-t", "0.3", "--d-r", "0.3",
                   "-o", tmp_path / "old"])
    assert new.exit_code == 0 and old.exit_code == 0, new.output + old.output
    a = pd.read_csv(tmp_path / "new" / "trajectory.csv")
    assert len(a) == 5 and a.equals(pd.read_csv(tmp_path / "old" / "trajectory.csv"))
    movie, bg = _movie(tmp_path)
    radii = []
    for spelling in ("--vote-radius", "--radius"):
        out = tmp_path / spelling.strip("-")
        res = _invoke(["crop", movie, "-b", bg, "-i", "paper_60x_water", "-o", out, "--size",
                       "90", spelling, "30", "--no-plot"])
        assert res.exit_code == 0, res.output
        side = json.loads((out / "crops.csv.json").read_text())
        radii.append(side["settings"]["finder"]["radius_px"])
    assert radii == [30.0, 30.0]
    help_text = " ".join(_invoke(["crop", "--help"]).output.split())
    assert "--vote-radius, --radius" in help_text and "the old name, deprecated" in help_text


def test_fix_lists_each_models_parameters_and_saturation_its_default():
    text = " ".join(_invoke(["fit", "--help"]).output.split())
    rod = load_particle("rod_paper").model
    names = ", ".join(p.name for p in static_parameters(rod))
    assert f"spherocylinder: {names}" in text
    assert "x_um, y_um, z_um, orientation, alpha" in text
    for stage in ("fit", "prefit"):
        text = " ".join(_invoke([stage, "--help"]).output.split())
        assert "--saturation LEVEL" in text and "[default: none;" in text


def _table_with_particle(tmp_path, particle):
    res = _invoke(["simulate", "trajectory", "--n-frames", "120", "--d-t", "0.3", "--d-r", "0.5",
                   "--a-um", "0.3", "--b-um", "1.0", "-o", tmp_path / "traj"])
    assert res.exit_code == 0, res.output
    table = tmp_path / "traj" / "trajectory.csv"
    if particle is not None:
        side = table.with_name("trajectory.csv.json")
        doc = json.loads(side.read_text())
        doc["particle_model"] = particle["model"]
        doc.setdefault("config", {})["particle"] = particle
        side.write_text(json.dumps(doc))
    return table


@pytest.mark.parametrize("particle,model", [
    ({"model": "spherocylinder", "a_um": 0.3, "b_um": 1.0}, "rod"),
    ({"model": "janus", "radius_um": 0.5}, "janus"),
    ({"model": "dimer", "radius1_um": 0.5, "radius2_um": 0.5, "index1": [1.5, 0],
      "index2": [1.5, 0]}, "rod"),
    ({"model": "dimer", "radius1_um": 0.5, "radius2_um": 0.4}, None),
])
def test_model_from_the_sidecar(tmp_path, particle, model):
    table = _table_with_particle(tmp_path, particle)
    assert model_from_sidecar(table)[0] == model


def test_analyze_reads_the_model_from_the_sidecar(tmp_path):
    table = _table_with_particle(tmp_path, {"model": "spherocylinder", "a_um": 0.3,
                                            "b_um": 1.0})
    res = _invoke(["analyze", table, "-o", tmp_path / "a", "--no-plot"])
    assert res.exit_code == 0, res.output
    assert "model: rod (the fit's particle, a spherocylinder)" in res.output
    with_model = _invoke(["analyze", table, "-m", "rod", "-o", tmp_path / "b", "--no-plots"])
    assert with_model.exit_code == 0, with_model.output
    a = json.loads((tmp_path / "a" / "summary.json").read_text())["analysis"]
    b = json.loads((tmp_path / "b" / "summary.json").read_text())["analysis"]
    assert a == b
    assert not list((tmp_path / "a").glob("*.png")) and not list((tmp_path / "b").glob("*.png"))
    # a table whose sidecar names no particle: the user must say
    bare = _table_with_particle(tmp_path / "bare", None)
    res = _invoke(["analyze", bare, "-o", tmp_path / "c"])
    assert res.exit_code == 2 and "give --model (rod, janus, sphere)" in res.output
