"""A measured quantity: value, statistical error, unit, and its sensitivity to ``D_est``."""

from __future__ import annotations

from dataclasses import dataclass, field

__all__ = ["Measurement"]


@dataclass
class Measurement:
    """A measured quantity with its statistical error and its ``D_est`` sensitivity.

    Attributes
    ----------
    value, error : float
        The value and its 1-sigma statistical error, in ``unit``.
    unit : str
        ``um^2/s``, ``1/s``, ``nm``, ``deg`` or ``1``.
    sensitivity : dict
        ``"D_est x <factor>"`` -> the value found with the rejection's ``D_est`` scaled by
        that factor (filled in by the analysis when the rejection ran).
    """

    value: float
    error: float
    unit: str
    sensitivity: dict[str, float] = field(default_factory=dict)
