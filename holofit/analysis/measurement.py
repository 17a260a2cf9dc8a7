"""A measured quantity: value, statistical error, unit, and its sensitivity to ``D_est``."""

from __future__ import annotations

import math
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
    upper_limit : bool
        ``value`` is a one-sided 95 % upper limit (the data do not resolve the quantity from
        zero); ``error`` is then NaN.
    error_below, error_above : float
        Errors below and above the value where they differ (a diffusion coefficient's error
        grows with it, :func:`holofit.analysis.linefit.sided_errors`); NaN: equal to
        ``error``.
    """

    value: float
    error: float
    unit: str
    sensitivity: dict[str, float] = field(default_factory=dict)
    upper_limit: bool = False
    error_below: float = float("nan")
    error_above: float = float("nan")

    def sides(self) -> tuple[float, float]:
        """Errors below and above the value."""
        lo = self.error_below if math.isfinite(self.error_below) else self.error
        hi = self.error_above if math.isfinite(self.error_above) else self.error
        return lo, hi

    def pull(self, truth: float) -> float:
        """``(value - truth) / error``, with the error on the side of the truth."""
        lo, hi = self.sides()
        return (self.value - truth) / (hi if truth > self.value else lo)
