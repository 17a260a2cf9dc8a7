"""Instrument and particle-model configuration: TOML files loaded into validated dataclasses.

Every value is checked for presence, type and a physically sensible range, so that a unit slip
(a wavelength of 660 meant in nm, a radius of 500 meant in nm, a negative size) is caught when
the file is read, with a message that names the file, the key and what was expected.

Instrument file (``configs/instruments/*.toml``)::

    [instrument]
    name = "paper-60x-water"
    wavelength_um = 0.660        # vacuum wavelength
    medium_index = 1.33
    pixel_size_um = 0.1767       # in the sample plane
    polarization_deg = 0.0       # from lab x (image columns)
    bit_depth = 8
    numerical_aperture = 1.2     # optional: the objective (holofit.scattering.lens)
    spherical_aberration_rad = [-1.5, 0.4]   # optional: its pupil phase, rad (holofit.aberration)

``spherical_aberration_rad`` holds the coefficients ``c_0, c_1, ...`` of the objective's
spherical aberration in radians of pupil phase: ``c_0`` the 4th, ``c_1`` the 6th order in the
pupil radius, in the coordinate ``cos th - 1`` and with the sign and normalisation of HoloPy's
``spherical_aberration`` (Martin, Leahy & Manoharan 2022; :mod:`holofit.aberration`); it needs a
``numerical_aperture``. Absent or all zero: the ideal objective.

Particle-model file (``configs/particles/*.toml``)::

    [particle]
    model = "sphere"
    radius_um = 0.5
    index = 1.59                 # or [1.59, 0.001] for n + i k
"""

from __future__ import annotations

import dataclasses
import json
import math
import numbers
import re
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from holofit.aberration import MAX_SPHERICAL_TERMS, Aberration
from holofit.config_schema import (
    INDEX_RANGE,
    SIZE_RANGE_UM,
    ConfigError,
    Spec,
    nm_hint,
    read_toml,
    validate_table,
)
from holofit.dda.settings import DDASettings
from holofit.engines.select import select_engine
from holofit.optics import Optics
from holofit.particles import MODEL_TYPES, ParticleModel, Sphere
from holofit.scattering.theory import ScatteringEngine

__all__ = [
    "ConfigError",
    "Instrument",
    "ParticleConfig",
    "instrument_from_dict",
    "instrument_toml",
    "load_instrument",
    "load_particle",
    "read_toml",
    "resolve_config",
]


INSTRUMENT_SPECS: dict[str, Spec] = {
    "name": Spec("str", "a short name for the set-up"),
    "description": Spec("str", "free text", required=False, default=""),
    "wavelength_um": Spec("float", "the vacuum wavelength in um", 0.2, 2.0, hint=nm_hint),
    "medium_index": Spec("float", "the refractive index of the medium", 1.0, 2.0),
    "pixel_size_um": Spec(
        "float", "the pixel pitch in the sample plane in um", 0.005, 20.0, hint=nm_hint
    ),
    "polarization_deg": Spec(
        "float", "the polarisation angle from lab x (image columns) in degrees", -360.0, 360.0
    ),
    "bit_depth": Spec("int", "the camera bit depth", 1, 32),
    "frame_rate_hz": Spec("float", "frames per second", 1e-6, 1e7, required=False),
    "numerical_aperture": Spec("float", "the objective NA", 0.01, 1.7, required=False),
    "spherical_aberration_rad": Spec(
        "floats", "the objective's spherical-aberration coefficients in rad of pupil phase "
        f"(at most {MAX_SPHERICAL_TERMS}; holofit.aberration)", -1000.0, 1000.0, required=False),
    "magnification": Spec("float", "the total magnification", 1.0, 1000.0, required=False),
    "camera_pixel_um": Spec(
        "float", "the physical camera pixel pitch in um", 0.5, 100.0, required=False
    ),
    "camera": Spec("str", "the camera model", required=False, default=""),
    "read_noise_counts": Spec(
        "float", "the camera read noise in counts (rms)", 0.0, 1e4, required=False, default=0.0
    ),
    "source": Spec("str", "where the numbers come from", required=False, default=""),
}


@dataclass(frozen=True)
class Instrument:
    """A holographic microscope: illumination, medium, camera.

    Attributes
    ----------
    name : str
        Short name.
    wavelength_um : float
        Vacuum wavelength, um.
    medium_index : float
        Refractive index of the medium.
    pixel_size_um : float
        Pixel pitch in the sample plane, um.
    polarization_rad : float
        Incident polarisation angle from lab x, rad.
    bit_depth : int
        Camera bit depth.
    extra : dict
        Optional descriptive values (NA, magnification, camera, frame rate, source).
    path : str
        File it was read from ("" if built in code).
    """

    name: str
    wavelength_um: float
    medium_index: float
    pixel_size_um: float
    polarization_rad: float = 0.0
    bit_depth: int = 8
    frame_rate_hz: float | None = None
    read_noise_counts: float = 0.0
    extra: dict[str, Any] = field(default_factory=dict, compare=False)
    path: str = ""

    @property
    def aberration(self) -> Aberration:
        """The objective's pupil phase (``spherical_aberration_rad``; none if not set)."""
        return Aberration(tuple(self.extra.get("spherical_aberration_rad", ())))

    @property
    def optics(self) -> Optics:
        """The illumination as the scattering engines see it (with the objective's NA and
        aberration, if set)."""
        return Optics(self.wavelength_um, self.medium_index, self.polarization_rad,
                      self.extra.get("numerical_aperture"), self.aberration)

    def with_aberration(self, aberration: Aberration) -> Instrument:
        """This instrument with another pupil phase (``Aberration()``: the ideal objective).

        Raises
        ------
        ValueError
            If the aberration is not zero and the instrument has no numerical aperture.
        """
        extra = {k: v for k, v in self.extra.items() if k != "spherical_aberration_rad"}
        if not aberration.is_zero:
            Optics(self.wavelength_um, self.medium_index, self.polarization_rad,
                   self.extra.get("numerical_aperture"), aberration)  # checks it
            extra["spherical_aberration_rad"] = list(aberration.spherical)
        return dataclasses.replace(self, extra=extra)

    def with_numerical_aperture(self, numerical_aperture: float | None) -> Instrument:
        """This instrument with another objective NA (None: the ideal model, no lens, and so
        no pupil to aberrate: its spherical aberration is dropped too).

        Raises
        ------
        ValueError
            If the NA is not a positive number.
        """
        extra = {k: v for k, v in self.extra.items() if k != "numerical_aperture"}
        if numerical_aperture is not None:
            Optics(self.wavelength_um, self.medium_index, self.polarization_rad,
                   float(numerical_aperture))  # checks the value
            extra["numerical_aperture"] = float(numerical_aperture)
        else:
            extra.pop("spherical_aberration_rad", None)
        return dataclasses.replace(self, extra=extra)

    def as_dict(self) -> dict[str, Any]:
        """Plain dict for sidecar JSON files (units in the keys)."""
        return {
            "name": self.name,
            "wavelength_um": self.wavelength_um,
            "medium_index": self.medium_index,
            "pixel_size_um": self.pixel_size_um,
            "polarization_deg": math.degrees(self.polarization_rad),
            "bit_depth": self.bit_depth,
            "frame_rate_hz": self.frame_rate_hz,
            "read_noise_counts": self.read_noise_counts,
            **self.extra,
            "path": self.path,
        }


def _instrument(v: dict[str, Any], path: str) -> Instrument:
    """An Instrument from validated instrument-table values.

    Raises
    ------
    ConfigError
        If the spherical aberration has too many coefficients or no numerical aperture to
        belong to.
    """
    extra = {
        k: v[k]
        for k in ("description", "numerical_aperture", "magnification", "camera_pixel_um",
                  "camera", "source")
        if v.get(k) not in (None, "")
    }
    spherical = v.get("spherical_aberration_rad")
    if spherical is not None:
        try:
            ab = Aberration(tuple(spherical))
        except ValueError as exc:
            raise ConfigError(f"{path}: [instrument] key 'spherical_aberration_rad': {exc}"
                              ) from None
        if not ab.is_zero and v.get("numerical_aperture") is None:
            raise ConfigError(f"{path}: [instrument] key 'spherical_aberration_rad': an "
                              "aberrated pupil needs an objective: set numerical_aperture")
        if not ab.is_zero:
            extra["spherical_aberration_rad"] = list(ab.spherical)
    return Instrument(
        name=v["name"],
        wavelength_um=v["wavelength_um"],
        medium_index=v["medium_index"],
        pixel_size_um=v["pixel_size_um"],
        polarization_rad=math.radians(v["polarization_deg"]),
        bit_depth=v["bit_depth"],
        frame_rate_hz=v["frame_rate_hz"],
        read_noise_counts=v["read_noise_counts"],
        extra=extra,
        path=path,
    )


def load_instrument(path: str | Path) -> Instrument:
    """Load and validate an instrument TOML file.

    Parameters
    ----------
    path : str or Path
        The file, or the name of a shipped or installed one (``"paper_60x_water"``; see
        :func:`resolve_config`).

    Raises
    ------
    ConfigError
        With the file, the key and what was expected.
    """
    path = resolve_config(path, "instruments")
    doc = read_toml(path)
    if "instrument" not in doc or not isinstance(doc["instrument"], dict):
        raise ConfigError(f"{path}: expected an [instrument] table")
    return _instrument(validate_table(doc["instrument"], INSTRUMENT_SPECS, path, "instrument"),
                       str(path))


def instrument_from_dict(doc: Mapping[str, Any], source: str = "<dict>") -> Instrument:
    """An :class:`Instrument` from its :meth:`Instrument.as_dict` form (e.g. a sidecar JSON).

    Keys as in an instrument file; ``path`` and null values are ignored; ``name``,
    ``polarization_deg`` and ``bit_depth`` default to ``"from-sidecar"``, 0 and 8.

    Raises
    ------
    ConfigError
        Missing or implausible values, naming ``source`` and the key.
    """
    table = {k: v for k, v in doc.items() if v is not None and k != "path"}
    table.setdefault("name", "from-sidecar")
    table.setdefault("polarization_deg", 0.0)
    table.setdefault("bit_depth", 8)
    known = {k: v for k, v in table.items() if k in INSTRUMENT_SPECS}
    values = validate_table(known, INSTRUMENT_SPECS, Path(source), "instrument")
    return _instrument(values, str(doc.get("path", "")))



_BARE_KEY = re.compile(r"^[A-Za-z0-9_-]+$")


def _toml_key(key: str) -> str:
    return key if _BARE_KEY.match(key) else json.dumps(key)


def _toml_value(value: Any) -> str:
    """A TOML value: strings, booleans, integers, floats (``repr``: round-trips; nan, inf)
    and arrays of them."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False)
    if isinstance(value, numbers.Integral):
        return str(int(value))
    if isinstance(value, numbers.Real):
        return repr(float(value))
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    raise TypeError(f"no TOML form for {value!r}")


def _toml_table(name: str, table: Mapping[str, Any]) -> list[str]:
    """``[name]`` and its keys; a mapping value becomes the subtable ``[name.key]``."""
    lines = [f"[{name}]"]
    subtables = []
    for key, value in table.items():
        if isinstance(value, Mapping):
            subtables.append((f"{name}.{_toml_key(key)}", value))
        elif value is not None:
            lines.append(f"{_toml_key(key)} = {_toml_value(value)}")
    for sub, value in subtables:
        lines += ["", *_toml_table(sub, value)]
    return lines


def instrument_toml(instrument: Instrument, *, comments: Sequence[str] = (),
                    tables: Mapping[str, Mapping[str, Any]] | None = None) -> str:
    """The text of an instrument file for ``instrument`` that :func:`load_instrument` reads
    back to the same values.

    Parameters
    ----------
    instrument : Instrument
        What the ``[instrument]`` table holds (its keys of :data:`INSTRUMENT_SPECS`; the
        polarisation in degrees, as the file gives it).
    comments : sequence of str
        Lines of the comment written above the table (without ``#``).
    tables : mapping, optional
        Further top-level tables (``{"calibration": {...}}``; a mapping inside one becomes a
        subtable): :func:`load_instrument` reads ``[instrument]`` only, so they carry what
        the instrument's own keys cannot, e.g. a calibration's errors and provenance.

    Returns
    -------
    str

    Raises
    ------
    ConfigError
        If the instrument's values would not load (checked by reading the text back).
    """
    values = instrument.as_dict()
    table = {k: values[k] for k in INSTRUMENT_SPECS
             if k in values and values[k] is not None and values[k] != ""}
    lines = [f"# {c}".rstrip() for c in comments]
    lines += _toml_table("instrument", table)
    for name, extra in (tables or {}).items():
        if name == "instrument":
            raise ConfigError("instrument_toml: the [instrument] table is the instrument's own")
        lines += ["", *_toml_table(_toml_key(name), extra)]
    text = "\n".join(lines) + "\n"
    where = Path(instrument.path or "<written instrument>")
    doc = tomllib.loads(text)
    _instrument(validate_table(doc["instrument"], INSTRUMENT_SPECS, where, "instrument"),
                str(where))
    return text



def model_specs(kind: str) -> dict[str, Spec]:
    """Key specifications for the parameters of particle model ``kind``."""
    cls = MODEL_TYPES[kind]
    if kind == "voxels":
        return {
            "path": Spec("str", "the ADDA shape file (relative to this config file)"),
            "dipole_size_um": Spec("float", "the dipole size in um", 0.001, 1.0, hint=nm_hint),
            "indices": Spec("indices", "the refractive index of each domain"),
            "centre_um": Spec("vector3", "the particle centre relative to the dipole box "
                              "centre, um", required=False, default=(0.0, 0.0, 0.0)),
        }
    if kind == "cluster":
        return {
            "radii_um": Spec("lengths", "the sphere radii in um", *SIZE_RANGE_UM, hint=nm_hint),
            "indices": Spec("indices", "the refractive index of each sphere"),
            "positions_um": Spec("vectors", "the sphere centres in the particle frame, um"),
        }
    specs: dict[str, Spec] = {}
    for name in (f.name for f in dataclasses.fields(cls)):
        if name in cls.size_fields:
            specs[name] = Spec("float", f"{name.removesuffix('_um')} in um", *SIZE_RANGE_UM,
                               hint=nm_hint)
        elif name in cls.nonnegative_fields:
            specs[name] = Spec("float", f"{name.removesuffix('_um')} in um (>= 0)", 0.0,
                               SIZE_RANGE_UM[1], hint=nm_hint)
        elif name in cls.index_fields:
            specs[name] = Spec("index", "an absolute refractive index", *INDEX_RANGE)
        else:
            specs[name] = Spec("float", f"{name}", None, None)
    return specs


@dataclass(frozen=True)
class ParticleConfig:
    """A particle model read from a file, with engine settings for it.

    Attributes
    ----------
    model : ParticleModel
        The particle.
    settings : dict
        Further tables of the file (e.g. ``[dda]``), validated by the code that uses them.
    path : str
        File it was read from.
    """

    model: ParticleModel
    settings: dict[str, Any] = field(default_factory=dict, compare=False)
    path: str = ""

    def as_dict(self) -> dict[str, Any]:
        params = {
            k: ([v.real, v.imag] if isinstance(v, complex) else v)
            for k, v in self.model.parameters().items()
        }
        return {"model": self.model.kind, **params, "settings": self.settings, "path": self.path}

    def dda_settings(self) -> DDASettings:
        """The ``[dda]`` table as :class:`holofit.dda.settings.DDASettings` (defaults if absent)."""
        return DDASettings.from_dict(self.settings.get("dda", {}), self.path)

    def with_fixed_lattice(self, optics: Optics) -> ParticleConfig:
        """This config with its DDA dipole size written out (``[dda] dipole_size_um``), as the
        dipoles-per-wavelength rule gives it for this particle in ``optics``; unchanged for a
        sphere computed by Lorenz-Mie. Stages that vary the particle's sizes or indices use it
        so that every model they compute sits on one lattice."""
        if isinstance(self.model, Sphere) and "dda" not in self.settings:
            return self
        table = dict(self.settings.get("dda", {}))
        if table.get("dipole_size_um") is None:
            table["dipole_size_um"] = self.dda_settings().dipole_size_for(self.model, optics)
        return dataclasses.replace(self, settings={**self.settings, "dda": table})

    def theory(self, engine: str | None = None, fixed_lattice_for: Optics | None = None
               ) -> ScatteringEngine:
        """The scattering engine for this particle (:func:`holofit.engines.select.select_engine`:
        the exact one where it has one - Lorenz-Mie for a sphere without a ``[dda]`` table, the
        exact T-matrix of a body of revolution - else the ``[dda]`` table's engine), or the one
        ``engine`` names. A ``[dda]`` table that names its ``engine`` (``builtin`` or
        ``adda``) chooses it under ``auto``: that is how a config asks for the DDA.

        Parameters
        ----------
        engine : str, optional
            Overrides the choice (``mie``, ``builtin``, ``adda``, ``exact``, ``auto``).
        fixed_lattice_for : Optics, optional
            Freeze a DDA engine's dipole size at the value the dipoles-per-wavelength rule gives
            for this particle in these optics, and an exact engine's order and radial steps at
            its reference build of this particle (a fit must: a rule that followed a fitted
            size or index would move the lattice or the order, and the residuals would jump).

        Raises
        ------
        ConfigError
            Naming this file, if the engine cannot handle the particle.
        """
        settings = self.dda_settings() if "dda" in self.settings else None
        if fixed_lattice_for is not None:
            base = settings or DDASettings()
            d = base.dipole_size_for(self.model, fixed_lattice_for)
            if settings is not None or not isinstance(self.model, Sphere):
                settings = base.replace(dipole_size_um=d)
        if (engine in (None, "auto") and settings is not None
                and "engine" in self.settings.get("dda", {})):
            engine = settings.engine
        try:
            theory = select_engine(self.model, settings, engine)
        except ValueError as exc:
            raise ConfigError(f"{self.path}: {exc}") from None
        fix = getattr(theory, "fix_discretisation", None)
        if fixed_lattice_for is not None and fix is not None:
            fix(self.model, fixed_lattice_for, lazy=True)
        return theory


def load_particle(path: str | Path) -> ParticleConfig:
    """Load and validate a particle-model TOML file.

    Parameters
    ----------
    path : str or Path
        The file, or the name of a shipped or installed one (``"rod_paper"``; see
        :func:`resolve_config`).

    Raises
    ------
    ConfigError
        With the file, the key and what was expected.
    """
    path = resolve_config(path, "particles")
    doc = read_toml(path)
    table = doc.get("particle")
    if not isinstance(table, dict):
        raise ConfigError(f"{path}: expected a [particle] table")
    kind = table.get("model")
    if not isinstance(kind, str) or kind not in MODEL_TYPES:
        raise ConfigError(
            f"{path}: [particle] key 'model': expected one of "
            f"{', '.join(sorted(MODEL_TYPES))}, got {kind!r}"
        )
    params = dict(table)
    params.pop("model")
    specs = model_specs(kind)
    specs["description"] = Spec("str", "free text", required=False, default="")
    values = validate_table(params, specs, path, "particle")
    values.pop("description")
    if kind == "voxels":
        shape_file = Path(values["path"])
        if not shape_file.is_absolute():
            shape_file = path.parent / shape_file
        if not shape_file.is_file():
            raise ConfigError(f"{path}: [particle] key 'path': shape file {shape_file} not found")
        values["path"] = str(shape_file)
    try:
        model = MODEL_TYPES[kind](**values)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{path}: [particle]: {exc}") from None
    settings = {k: v for k, v in doc.items() if k != "particle"}
    if "dda" in settings:
        if not isinstance(settings["dda"], dict):
            raise ConfigError(f"{path}: [dda] must be a table")
        DDASettings.from_dict(settings["dda"], path)  # validate now, with the file's name
    return ParticleConfig(model=model, settings=settings, path=str(path))


def config_search_path(kind: str) -> list[Path]:
    """Folders searched for a config given by name: ``$HOLOFIT_CONFIG_DIR/<kind>``,
    ``./configs/<kind>``, the ``configs/<kind>`` folder of a source checkout, and the configs
    installed with the package (``<prefix>/share/holofit/configs/<kind>``)."""
    import os
    import sys

    dirs = []
    env = os.environ.get("HOLOFIT_CONFIG_DIR")
    if env:
        dirs.append(Path(env) / kind)
    dirs.append(Path.cwd() / "configs" / kind)
    dirs.append(Path(__file__).resolve().parents[1] / "configs" / kind)
    dirs.append(Path(sys.prefix) / "share" / "holofit" / "configs" / kind)
    return list(dict.fromkeys(dirs))  # once each (the current folder may be the checkout)


def config_names(kind: str) -> list[str]:
    """The names of every config of ``kind`` in :func:`config_search_path`, sorted."""
    return sorted({f.stem for d in config_search_path(kind) if d.is_dir()
                   for f in d.glob("*.toml")})


def _by_name(path: Path, kind: str) -> bool:
    """A bare name, or a path into a ``configs/<kind>`` folder (the README's examples):
    looked up by name when the file is not there."""
    parts = path.parts[:-1]
    return not parts or tuple(parts[-2:]) == ("configs", kind)


def resolve_config(name_or_path: str | Path, kind: str) -> Path:
    """A config file given as a path or as a bare name (``paper_60x_water``).

    Parameters
    ----------
    name_or_path : str or Path
        Existing file, or a name looked up in :func:`config_search_path` (``.toml`` optional,
        ``-`` and ``_`` interchangeable). A path into a ``configs/<kind>`` folder that does
        not exist from here (``configs/instruments/paper_60x_water.toml`` run outside the
        checkout) is looked up by its name.
    kind : str
        ``"instruments"`` or ``"particles"``.

    Raises
    ------
    ConfigError
        No such file or name; the message suggests the nearest names and lists those there are.
    """
    p = Path(name_or_path)
    if p.is_file():
        return p
    if not _by_name(p, kind):
        raise ConfigError(f"{p}: configuration file not found")
    stem = p.name.removesuffix(".toml")
    for folder in config_search_path(kind):
        for candidate in (stem, stem.replace("-", "_")):
            f = folder / f"{candidate}.toml"
            if f.is_file():
                return f
    import difflib

    names = config_names(kind)
    close = difflib.get_close_matches(stem.replace("-", "_"), names, n=3, cutoff=0.75)
    guess = f" (did you mean {' or '.join(close)}?)" if close else ""
    there = f"; the {kind}: {', '.join(names)}" if names else ""
    searched = ", ".join(str(d) for d in config_search_path(kind))
    raise ConfigError(
        f"{name_or_path}: no such {kind[:-1]} config{guess}{there} (searched {searched})"
    )
