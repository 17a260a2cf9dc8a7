"""Configuration files load into validated dataclasses; mistakes name file, key, expectation."""

import math
from pathlib import Path

import pytest

from holofit.config import ConfigError, load_instrument, load_particle, resolve_config
from holofit.particles import Sphere
from tests.conftest import CONFIGS

GOOD = """
[instrument]
name = "t"
wavelength_um = 0.66
medium_index = 1.33
pixel_size_um = 0.1
polarization_deg = 90.0
bit_depth = 8
"""


def _write(tmp_path: Path, text: str, name: str = "cfg.toml") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


@pytest.mark.parametrize("path", sorted((CONFIGS / "instruments").glob("*.toml")))
def test_all_instrument_configs_load(path):
    inst = load_instrument(path)
    assert 0.2 < inst.wavelength_um < 2.0 and inst.pixel_size_um > 0
    assert inst.optics.k == pytest.approx(2 * math.pi * inst.medium_index / inst.wavelength_um)


@pytest.mark.parametrize("path", sorted((CONFIGS / "particles").glob("*.toml")))
def test_all_particle_configs_load(path):
    cfg = load_particle(path)
    assert cfg.model.kind


def test_paper_pixel_sizes_follow_camera_and_magnification():
    for name, mag in (("paper_60x_water", 60), ("paper_100x_oil", 100)):
        inst = load_instrument(resolve_config(name, "instruments"))
        assert inst.pixel_size_um == pytest.approx(inst.extra["camera_pixel_um"] / mag, rel=1e-3)
        assert inst.wavelength_um == 0.66 and inst.medium_index == 1.33


def test_polarization_in_degrees_becomes_radians(tmp_path):
    inst = load_instrument(_write(tmp_path, GOOD))
    assert inst.polarization_rad == pytest.approx(math.pi / 2)


def test_missing_key_names_file_and_key(tmp_path):
    p = _write(tmp_path, GOOD.replace("medium_index = 1.33\n", ""))
    with pytest.raises(ConfigError, match=r"cfg\.toml.*missing key 'medium_index'"):
        load_instrument(p)


def test_wrong_type_names_key_and_expectation(tmp_path):
    p = _write(tmp_path, GOOD.replace("bit_depth = 8", 'bit_depth = "eight"'))
    with pytest.raises(ConfigError, match=r"cfg\.toml.*'bit_depth'.*integer|number"):
        load_instrument(p)


def test_wavelength_in_nm_is_caught_with_advice(tmp_path):
    p = _write(tmp_path, GOOD.replace("wavelength_um = 0.66", "wavelength_um = 660"))
    with pytest.raises(
        ConfigError,
        match=r"cfg\.toml.*'wavelength_um'.*vacuum wavelength in um"
        r".*660.*nanometres.*0\.66 um",
    ):
        load_instrument(p)


def test_unknown_key_is_a_typo(tmp_path):
    p = _write(tmp_path, GOOD + "pixel_sise_um = 0.1\n")
    with pytest.raises(ConfigError, match=r"unknown key.*pixel_sise_um"):
        load_instrument(p)


def test_bad_toml_names_file(tmp_path):
    p = _write(tmp_path, "[instrument\nname=")
    with pytest.raises(ConfigError, match=r"cfg\.toml: not valid TOML"):
        load_instrument(p)


def test_particle_negative_radius(tmp_path):
    p = _write(tmp_path, '[particle]\nmodel = "sphere"\nradius_um = -0.5\nindex = 1.59\n')
    with pytest.raises(ConfigError, match=r"cfg\.toml.*'radius_um'.*radius in um.*-0\.5"):
        load_particle(p)


def test_particle_radius_in_nm(tmp_path):
    p = _write(tmp_path, '[particle]\nmodel = "sphere"\nradius_um = 500\nindex = 1.59\n')
    with pytest.raises(ConfigError, match="nanometres"):
        load_particle(p)


def test_particle_complex_index_and_negative_absorption(tmp_path):
    p = _write(tmp_path, '[particle]\nmodel = "sphere"\nradius_um = 0.5\nindex = [1.59, 0.01]\n')
    model = load_particle(p).model
    assert isinstance(model, Sphere) and model.index == complex(1.59, 0.01)
    p = _write(tmp_path, '[particle]\nmodel = "sphere"\nradius_um = 0.5\nindex = [1.59, -0.01]\n')
    with pytest.raises(ConfigError, match="imaginary part"):
        load_particle(p)


def test_unknown_model(tmp_path):
    p = _write(tmp_path, '[particle]\nmodel = "banana"\n')
    with pytest.raises(ConfigError, match=r"'model'.*expected one of"):
        load_particle(p)


def test_resolve_by_name_and_unknown_name():
    assert resolve_config("paper-60x-water", "instruments").name == "paper_60x_water.toml"
    with pytest.raises(ConfigError, match="no such instrument config"):
        resolve_config("nope", "instruments")
