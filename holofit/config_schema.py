"""The validation library of configuration files: typed, range-checked keys with messages
that name the file, the table and the key.

Schemas (which keys an instrument or a particle file has) live with the code that owns them
(:mod:`holofit.config`, :mod:`holofit.dda.settings`); this module only knows how to check a
table against one, so that a unit slip (a wavelength of 660 meant in nm, a radius of 500 meant
in nm, a negative size) or a misspelled key is caught when the file is read.
"""

from __future__ import annotations

import difflib
import math
import tomllib
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

__all__ = [
    "INDEX_RANGE",
    "SIZE_RANGE_UM",
    "ConfigError",
    "Spec",
    "celsius_hint",
    "nm_hint",
    "number_problem",
    "read_toml",
    "validate_table",
]

#: plausible range of a particle length (um); outside it a unit slip is likely
SIZE_RANGE_UM = (0.005, 100.0)
#: plausible range of the real part of an absolute refractive index
INDEX_RANGE = (1.0, 5.0)


class ConfigError(ValueError):
    """A configuration file is missing a key, has a wrong type or an implausible value."""


@dataclass(frozen=True)
class Spec:
    """What one configuration key must hold."""

    # "float", "int", "str", "bool", "index", "indices", "vector3", "lengths", "vectors",
    # "floats" (a list of numbers, each within low..high)
    kind: str
    expected: str  # human description, with unit
    low: float | None = None
    high: float | None = None
    required: bool = True
    default: Any = None
    #: extra advice when the value is out of range (e.g. a unit slip)
    hint: Callable[[float], str] | None = None


def nm_hint(value: float) -> str:
    if value > 100:
        return f" ({value} looks like nanometres: use {value / 1000:g} um)"
    return ""


def celsius_hint(value: float) -> str:
    """Advice for a temperature in C that is out of range: one given in kelvin."""
    if 173.15 <= value <= 473.15:
        return f" ({value:g} looks like kelvin: use {value - 273.15:.4g} C)"
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
    if spec.kind == "floats":
        if (not isinstance(value, list)
                or not all(isinstance(v, int | float) and not isinstance(v, bool) for v in value)):
            raise ConfigError(f"{loc}: expected {spec.expected} as a list of numbers, got "
                              f"{value!r}")
        sub = Spec("float", spec.expected, spec.low, spec.high, hint=spec.hint)
        return tuple(float(_check_value(path, where, f"{key}[{i}]", v, sub))
                     for i, v in enumerate(value))
    if spec.kind == "lengths":
        if (not isinstance(value, list) or not value
                or not all(isinstance(v, int | float) and not isinstance(v, bool) for v in value)):
            raise ConfigError(f"{loc}: expected {spec.expected} as a list of numbers, got "
                              f"{value!r}")
        sub = Spec("float", "a length in um", spec.low, spec.high, hint=spec.hint)
        return tuple(float(_check_value(path, where, f"{key}[{i}]", v, sub))
                     for i, v in enumerate(value))
    if spec.kind == "vectors":
        if not isinstance(value, list) or not value:
            raise ConfigError(f"{loc}: expected {spec.expected} as a list of [x, y, z], got "
                              f"{value!r}")
        sub = Spec("vector3", "[x, y, z] in um")
        return tuple(_check_value(path, where, f"{key}[{i}]", v, sub)
                     for i, v in enumerate(value))
    if spec.kind == "vector3":
        if (not isinstance(value, list) or len(value) != 3
                or not all(isinstance(v, int | float) and not isinstance(v, bool) for v in value)):
            raise ConfigError(f"{loc}: expected {spec.expected} as [x, y, z], got {value!r}")
        return tuple(float(v) for v in value)
    problem = number_problem(value, spec)
    if problem:
        raise ConfigError(f"{loc}: {problem}")
    return int(value) if spec.kind == "int" else float(value)


def number_problem(value: Any, spec: Spec) -> str | None:
    """What is wrong with ``value`` as the number ``spec`` describes, or None.

    The check of every numeric key (kind ``float`` or ``int``): type, finiteness, range, with
    the spec's hint for a likely unit slip. Values that do not come from a file (keyword
    arguments, command-line options) are checked with it too, so that a setting is held to
    the same rule wherever it is given; the caller says where the value came from.
    """
    if isinstance(value, bool) or not isinstance(value, int | float):
        return f"expected {spec.expected} (a number), got {value!r}"
    if spec.kind == "int":
        if not isinstance(value, int):
            return f"expected {spec.expected} (an integer), got {value!r}"
    elif not math.isfinite(value):
        return f"expected {spec.expected}, got {value!r}"
    return _range_problem(float(value), spec)


def _range_problem(value: float, spec: Spec) -> str | None:
    lo, hi = spec.low, spec.high
    if (lo is not None and value < lo) or (hi is not None and value > hi):
        bounds = (
            f"between {lo:g} and {hi:g}"
            if lo is not None and hi is not None
            else (f">= {lo:g}" if lo is not None else f"<= {hi:g}")
        )
        extra = spec.hint(value) if spec.hint else ""
        return f"expected {spec.expected} {bounds}, got {value:g}{extra}"
    return None


def _check_range(loc: str, value: float, spec: Spec) -> None:
    problem = _range_problem(value, spec)
    if problem:
        raise ConfigError(f"{loc}: {problem}")


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
    """Check a TOML table against ``specs``.

    Parameters
    ----------
    table : mapping
        The table as read.
    specs : mapping
        Key -> :class:`Spec`, in the order keys are checked.
    path : Path
        The file, for messages.
    where : str
        The table's name, for messages (``instrument``, ``particle``, ``dda``).

    Returns
    -------
    dict
        Every key of ``specs``: the checked value or the spec's default.

    Raises
    ------
    ConfigError
        A missing required key, a wrong type, a value out of range (with a unit hint where one
        applies), or an unknown key (a typo: the closest valid key is suggested).
    """
    _check_keys(table, specs, path, where)
    out: dict[str, Any] = {}
    for key, spec in specs.items():
        out[key] = (
            _check_value(path, where, key, table[key], spec) if key in table else spec.default
        )
    return out


def _check_keys(table: Mapping[str, Any], specs: Mapping[str, Spec], path: Path,
                where: str) -> None:
    """Every unknown and every missing key at once, a typo named with the key it stands for."""
    unknown = sorted(set(table) - set(specs))
    missing = [key for key, spec in specs.items() if spec.required and key not in table]
    if not unknown and not missing:
        return
    parts = []
    explained: set[str] = set()
    if unknown:
        named = []
        for key in unknown:
            close = difflib.get_close_matches(
                key, [k for k in specs if k not in table], n=1, cutoff=0.6
            )
            if close:
                explained.add(close[0])
                named.append(f"'{key}' (did you mean '{close[0]}', {specs[close[0]].expected}?)")
            else:
                named.append(f"'{key}'")
        parts.append(f"has unknown key{'s' if len(unknown) > 1 else ''} {', '.join(named)}")
    rest = [key for key in missing if key not in explained]
    if rest:
        listed = ", ".join(f"'{key}' ({specs[key].expected})" for key in rest)
        parts.append(f"is missing key{'s' if len(rest) > 1 else ''} {listed}")
    allowed = f"; allowed keys: {', '.join(specs)}" if unknown else ""
    raise ConfigError(f"{path}: [{where}] " + "; ".join(parts) + allowed)
