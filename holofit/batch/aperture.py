"""The stage's choice of the objective's numerical aperture: keep the instrument's, none (the
ideal model), or a value given on the command line; the instrument a fit then runs with.

The model kit (:mod:`holofit.holomodel.aperture`) fits an NA from a start value; reading the
choice and applying it to an :class:`~holofit.config.Instrument` belongs to the stages.
"""

from __future__ import annotations

import math
from typing import Literal

from holofit.config import ConfigError, Instrument

__all__ = ["FROM_INSTRUMENT", "ApertureChoice", "fit_instrument", "parse_numerical_aperture"]

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
