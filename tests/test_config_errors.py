"""Config errors read like every input failure, and configs are found by name from anywhere
(issue 24, items 7 and 10).

`holofit STAGE: error: MESSAGE`, exit status 1, no usage block: a key typo, a value out of
range (a radius of 500 meant in nm), a missing file, a misspelt name (with the nearest names and
the list of those there are). The Python API takes the names the command line takes, and the
README's ``configs/...`` paths work from any folder.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from click.testing import CliRunner

from holofit.cli import main
from holofit.config import ConfigError, load_instrument, load_particle, resolve_config

ROOT = Path(__file__).resolve().parents[1]


def _invoke(args):
    return CliRunner().invoke(main, [str(a) for a in args])


def _assert_stage_error(res, stage, *fragments):
    assert res.exit_code == 1, res.output
    assert res.output.startswith(f"holofit {stage}: error: "), res.output
    assert "Usage:" not in res.output and "Invalid value" not in res.output
    text = " ".join(res.output.split())
    for fragment in fragments:
        assert fragment in text, (fragment, text)


def test_a_misspelt_config_name_suggests_the_right_one(tmp_path):
    res = _invoke(["crop", tmp_path / "m.tif", "--normalized", "-i", "paper_60x_waterr",
                   "-o", tmp_path / "o"])
    _assert_stage_error(res, "crop", "paper_60x_waterr: no such instrument config",
                        "did you mean paper_60x_water?", "paper_100x_oil", "pylorenzmie")
    with pytest.raises(ConfigError, match="did you mean rod_paper"):
        load_particle("rod_papr")


def test_a_value_out_of_range_and_a_missing_file(tmp_path):
    bad = tmp_path / "big.toml"
    bad.write_text('[particle]\nmodel = "sphere"\nradius_um = 500\nindex = 1.59\n')
    res = _invoke(["simulate", "hologram", "-p", bad, "--position", "5,5,10", "--shape",
                   "32,32", "-o", tmp_path / "sim"])
    _assert_stage_error(res, "simulate hologram", f"{bad}: [particle] key 'radius_um'",
                        "looks like nanometres: use 0.5 um")
    missing = tmp_path / "nowhere" / "scope.toml"
    res = _invoke(["crop", tmp_path / "m.tif", "--normalized", "-i", missing,
                   "-o", tmp_path / "o"])
    _assert_stage_error(res, "crop", f"{missing}: configuration file not found")


def test_the_api_takes_names_and_readme_paths_from_any_folder(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # not the checkout
    by_name = load_instrument("paper_60x_water")
    by_path = load_instrument("configs/instruments/paper_60x_water.toml")
    direct = load_instrument(ROOT / "configs" / "instruments" / "paper_60x_water.toml")
    assert by_name == direct and by_path == direct
    assert load_particle("configs/particles/rod_paper.toml").model == load_particle(
        ROOT / "configs" / "particles" / "rod_paper.toml").model
    # a path elsewhere that does not exist is not replaced by a shipped config of that name
    with pytest.raises(ConfigError, match="configuration file not found"):
        resolve_config(tmp_path / "elsewhere" / "paper_60x_water.toml", "instruments")


def test_installed_configs_are_found_by_name(tmp_path, monkeypatch):
    """A wheel installs the shipped configs under <prefix>/share/holofit/configs (pyproject's
    data-files); names resolve there when no checkout is at hand."""
    import sys
    import tomllib

    data_files = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"][
        "data-files"]
    for kind in ("instruments", "particles"):
        assert data_files[f"share/holofit/configs/{kind}"] == [f"configs/{kind}/*.toml"]
    folder = tmp_path / "share" / "holofit" / "configs" / "instruments"
    folder.mkdir(parents=True)
    text = (ROOT / "configs" / "instruments" / "paper_100x_oil.toml").read_text()
    (folder / "installed_scope.toml").write_text(text)
    monkeypatch.setattr(sys, "prefix", str(tmp_path))
    monkeypatch.chdir(tmp_path)
    assert load_instrument("installed_scope").path == str(folder / "installed_scope.toml")
