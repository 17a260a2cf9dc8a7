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

Particle-model file (``configs/particles/*.toml``)::

    [particle]
    model = "sphere"
    radius_um = 0.5
    index = 1.59                 # or [1.59, 0.001] for n + i k
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from holofit.models import MODEL_TYPES, ParticleModel
from holofit.optics import Optics

__all__ = [
    "ConfigError",
    "Instrument",
    "ParticleConfig",
    "instrument_from_dict",
    "load_instrument",
    "load_particle",
    "read_toml",
]


class ConfigError(ValueError):
    """A configuration file is missing a key, has a wrong type or an implausible value."""


@dataclass(frozen=True)
class Spec:
    """What one configuration key must hold."""

    kind: str  # "float", "int", "str", "bool", "index"
    expected: str  # human description, with unit
    low: float | None = None
    high: float | None = None
    required: bool = True
    default: Any = None
    #: extra advice when the value is out of range (e.g. a unit slip)
    hint: Callable[[float], str] | None = None


def _nm_hint(value: float) -> str:
    if value > 100:
        return f" ({value} looks like nanometres: use {value / 1000:g} um)"
    return ""


def read_toml(path: str | Path) -> dict[str, Any]:
    """Read a TOML file, turning syntax errors into a :class:`ConfigError` naming the file."""
    path = Path(path)
    try:
        with path.open("rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError:
        raise ConfigError(f"{path}: configuration file not found") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML: {exc}") from None


def _check_value(path: Path, where: str, key: str, value: Any, spec: Spec) -> Any:
    loc = f"{path}: [{where}] key '{key}'"
    if spec.kind == "str":
        if not isinstance(value, str):
            raise ConfigError(f"{loc}: expected {spec.expected} (a string), got {value!r}")
        return value
    if spec.kind == "bool":
        if not isinstance(value, bool):
            raise ConfigError(f"{loc}: expected {spec.expected} (true/false), got {value!r}")
        return value
    if spec.kind == "index":
        return _check_index(loc, value, spec)
    if spec.kind == "indices":
        if not isinstance(value, list) or not value:
            raise ConfigError(f"{loc}: expected {spec.expected} as a list, got {value!r}")
        sub = Spec("index", "an absolute refractive index", *INDEX_RANGE)
        return tuple(_check_index(f"{loc}[{i}]", v, sub) for i, v in enumerate(value))
    if spec.kind == "vector3":
        if (not isinstance(value, list) or len(value) != 3
                or not all(isinstance(v, int | float) and not isinstance(v, bool) for v in value)):
            raise ConfigError(f"{loc}: expected {spec.expected} as [x, y, z], got {value!r}")
        return tuple(float(v) for v in value)
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ConfigError(f"{loc}: expected {spec.expected} (a number), got {value!r}")
    if spec.kind == "int":
        if not isinstance(value, int):
            raise ConfigError(f"{loc}: expected {spec.expected} (an integer), got {value!r}")
    elif not math.isfinite(value):
        raise ConfigError(f"{loc}: expected {spec.expected}, got {value!r}")
    _check_range(loc, float(value), spec)
    return int(value) if spec.kind == "int" else float(value)


def _check_range(loc: str, value: float, spec: Spec) -> None:
    lo, hi = spec.low, spec.high
    if (lo is not None and value < lo) or (hi is not None and value > hi):
        bounds = (
            f"between {lo:g} and {hi:g}"
            if lo is not None and hi is not None
            else (f">= {lo:g}" if lo is not None else f"<= {hi:g}")
        )
        extra = spec.hint(value) if spec.hint else ""
        raise ConfigError(f"{loc}: expected {spec.expected} {bounds}, got {value:g}{extra}")


def _check_index(loc: str, value: Any, spec: Spec) -> complex:
    if isinstance(value, bool):
        raise ConfigError(f"{loc}: expected {spec.expected}, got {value!r}")
    if isinstance(value, int | float):
        re_, im_ = float(value), 0.0
    elif (
        isinstance(value, list)
        and len(value) == 2
        and all(isinstance(v, int | float) and not isinstance(v, bool) for v in value)
    ):
        re_, im_ = float(value[0]), float(value[1])
    else:
        raise ConfigError(
            f"{loc}: expected {spec.expected} as a number or a pair [n, k], got {value!r}"
        )
    _check_range(loc, re_, spec)
    if im_ < 0:
        raise ConfigError(
            f"{loc}: the imaginary part of a refractive index must be >= 0 (absorption, "
            f"exp(-i omega t) convention), got {im_:g}"
        )
    return complex(re_, im_)


def validate_table(
    table: Mapping[str, Any], specs: Mapping[str, Spec], path: Path, where: str
) -> dict[str, Any]:
    """Check a TOML table against ``specs``; unknown keys are errors too (typos)."""
    out: dict[str, Any] = {}
    for key, spec in specs.items():
        if key not in table:
            if spec.required:
                raise ConfigError(f"{path}: [{where}] is missing key '{key}' ({spec.expected})")
            out[key] = spec.default
            continue
        out[key] = _check_value(path, where, key, table[key], spec)
    unknown = sorted(set(table) - set(specs))
    if unknown:
        raise ConfigError(
            f"{path}: [{where}] has unknown key(s) {', '.join(map(repr, unknown))}; "
            f"allowed: {', '.join(specs)}"
        )
    return out


INSTRUMENT_SPECS: dict[str, Spec] = {
    "name": Spec("str", "a short name for the set-up"),
    "description": Spec("str", "free text", required=False, default=""),
    "wavelength_um": Spec("float", "the vacuum wavelength in um", 0.2, 2.0, hint=_nm_hint),
    "medium_index": Spec("float", "the refractive index of the medium", 1.0, 2.0),
    "pixel_size_um": Spec(
        "float", "the pixel pitch in the sample plane in um", 0.005, 20.0, hint=_nm_hint
    ),
    "polarization_deg": Spec(
        "float", "the polarisation angle from lab x (image columns) in degrees", -360.0, 360.0
    ),
    "bit_depth": Spec("int", "the camera bit depth", 1, 32),
    "frame_rate_hz": Spec("float", "frames per second", 1e-6, 1e7, required=False),
    "numerical_aperture": Spec("float", "the objective NA", 0.01, 1.7, required=False),
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
    def optics(self) -> Optics:
        """The illumination as the scattering engines see it."""
        return Optics(self.wavelength_um, self.medium_index, self.polarization_rad)

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
    """An Instrument from validated instrument-table values."""
    extra = {
        k: v[k]
        for k in ("description", "numerical_aperture", "magnification", "camera_pixel_um",
                  "camera", "source")
        if v.get(k) not in (None, "")
    }
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

    Raises
    ------
    ConfigError
        With the file, the key and what was expected.
    """
    path = Path(path)
    doc = read_toml(path)
    if "instrument" not in doc or not isinstance(doc["instrument"], dict):
        raise ConfigError(f"{path}: expected an [instrument] table")
    return _instrument(validate_table(doc["instrument"], INSTRUMENT_SPECS, path, "instrument"),
                       str(path))


def instrument_from_dict(doc: dict[str, Any], source: str = "<dict>") -> Instrument:
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


#: plausible range of a particle length (um); outside it a unit slip is likely
SIZE_RANGE_UM = (0.005, 100.0)
INDEX_RANGE = (1.0, 5.0)


def model_specs(kind: str) -> dict[str, Spec]:
    """Key specifications for the parameters of particle model ``kind``."""
    cls = MODEL_TYPES[kind]
    if kind == "voxels":
        return {
            "path": Spec("str", "the ADDA shape file (relative to this config file)"),
            "dipole_size_um": Spec("float", "the dipole size in um", 0.001, 1.0, hint=_nm_hint),
            "indices": Spec("indices", "the refractive index of each domain"),
            "centre_um": Spec("vector3", "the particle centre relative to the dipole box "
                              "centre, um", required=False, default=(0.0, 0.0, 0.0)),
        }
    specs: dict[str, Spec] = {}
    for name in (f.name for f in dataclasses.fields(cls)):
        if name in cls.size_fields:
            specs[name] = Spec("float", f"{name.removesuffix('_um')} in um", *SIZE_RANGE_UM,
                               hint=_nm_hint)
        elif name in cls.nonnegative_fields:
            specs[name] = Spec("float", f"{name.removesuffix('_um')} in um (>= 0)", 0.0,
                               SIZE_RANGE_UM[1], hint=_nm_hint)
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

    def dda_settings(self) -> Any:
        """The ``[dda]`` table as :class:`holofit.dda.settings.DDASettings` (defaults if absent)."""
        from holofit.dda.settings import DDASettings

        return DDASettings.from_dict(self.settings.get("dda", {}), self.path)


def load_particle(path: str | Path) -> ParticleConfig:
    """Load and validate a particle-model TOML file.

    Raises
    ------
    ConfigError
        With the file, the key and what was expected.
    """
    path = Path(path)
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
        from holofit.dda.settings import DDASettings

        if not isinstance(settings["dda"], dict):
            raise ConfigError(f"{path}: [dda] must be a table")
        DDASettings.from_dict(settings["dda"], path)  # validate now, with the file's name
    return ParticleConfig(model=model, settings=settings, path=str(path))


def config_search_path(kind: str) -> list[Path]:
    """Folders searched for a config given by name: ``$HOLOFIT_CONFIG_DIR/<kind>``,
    ``./configs/<kind>`` and the ``configs/<kind>`` folder of a source checkout."""
    import os

    dirs = []
    env = os.environ.get("HOLOFIT_CONFIG_DIR")
    if env:
        dirs.append(Path(env) / kind)
    dirs.append(Path.cwd() / "configs" / kind)
    dirs.append(Path(__file__).resolve().parents[1] / "configs" / kind)
    return dirs


def resolve_config(name_or_path: str | Path, kind: str) -> Path:
    """A config file given as a path or as a bare name (``paper_60x_water``).

    Parameters
    ----------
    name_or_path : str or Path
        Existing file, or a name looked up in :func:`config_search_path` (``.toml`` optional,
        ``-`` and ``_`` interchangeable).
    kind : str
        ``"instruments"`` or ``"particles"``.
    """
    p = Path(name_or_path)
    if p.is_file():
        return p
    stem = p.name.removesuffix(".toml")
    for folder in config_search_path(kind):
        for candidate in (stem, stem.replace("-", "_")):
            f = folder / f"{candidate}.toml"
            if f.is_file():
                return f
    searched = ", ".join(str(d) for d in config_search_path(kind))
    raise ConfigError(f"{name_or_path}: no such {kind[:-1]} config (searched {searched})")
