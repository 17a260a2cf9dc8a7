"""The objective's numerical aperture in a fit: the instrument's, another one, none, or fitted.

A fit images its model through the objective of the instrument (:mod:`holofit.scattering.lens`)
when the instrument has a ``numerical_aperture``, and uses the ideal model (the field in the
focal plane itself) when it has none. A stage can replace that NA (another value, or none) and
can fit it, starting from the NA in force. A fitted NA starts at most at the medium's index:
beyond it the lens collects every propagating wave and the hologram no longer changes.
"""

from __future__ import annotations

import math
from typing import Literal

from holofit.config import Instrument
from holofit.optics import Optics
from holofit.validation import ConfigError

__all__ = [
    "FROM_INSTRUMENT",
    "ApertureChoice",
    "aperture_start",
    "fit_instrument",
    "parse_numerical_aperture",
]

#: keep the instrument's NA (or its absence)
FROM_INSTRUMENT: Literal["instrument"] = "instrument"
#: what a stage is told about the NA: keep the instrument's, none (ideal model), or a value
ApertureChoice = float | None | Literal["instrument"]


def parse_numerical_aperture(text: str) -> float | None:
    """``"none"`` -> None (the ideal model), a positive number -> that NA.

    Raises
    ------
    ValueError
        Anything else.
    """
    word = text.strip().lower()
    if word in ("none", "ideal", "off"):
        return None
    try:
        value = float(word)
    except ValueError:
        raise ValueError(f"expected a numerical aperture (e.g. 1.2) or 'none', got {text!r}"
                         ) from None
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"a numerical aperture must be positive, got {text!r}")
    return value


def fit_instrument(instrument: Instrument, numerical_aperture: ApertureChoice = FROM_INSTRUMENT,
                   fit: bool = False) -> Instrument:
    """The instrument a fit runs with: its NA replaced if one is given (None: no lens).

    Parameters
    ----------
    instrument : Instrument
        The stage's instrument.
    numerical_aperture : float, None or "instrument"
        The objective's NA for the fit; ``"instrument"`` keeps the instrument's.
    fit : bool
        The NA will be fitted (it then needs a start value).

    Raises
    ------
    ConfigError
        Fitting the NA with none to start from, or an NA that is not positive.
    """
    inst = instrument
    if numerical_aperture != FROM_INSTRUMENT:
        try:
            inst = instrument.with_numerical_aperture(numerical_aperture)  # type: ignore[arg-type]
        except ValueError as exc:
            raise ConfigError(f"numerical aperture for the fit: {exc}") from None
    if fit and inst.optics.numerical_aperture is None:
        raise ConfigError(
            f"fitting the numerical aperture needs a start value: instrument {inst.name!r} "
            f"({inst.path or 'given'}) has no numerical_aperture; give one "
            "(--numerical-aperture NA)")
    return inst


def aperture_start(optics: Optics) -> float:
    """Start value of a fitted NA: the optics' NA, at most the medium's index.

    Raises
    ------
    ValueError
        If the optics have no NA.
    """
    if optics.numerical_aperture is None:
        raise ValueError("fitting the numerical aperture needs a start value: the optics have "
                         "no numerical_aperture")
    return float(min(optics.numerical_aperture, optics.n_medium))
