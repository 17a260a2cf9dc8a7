"""Errors and warnings of the ADDA adapter (:mod:`holofit.dda.adda`)."""

from __future__ import annotations

__all__ = [
    "AddaConvergenceError",
    "AddaError",
    "AddaFarFieldWarning",
    "AddaNotFoundError",
    "AddaWarning",
]


class AddaError(RuntimeError):
    """ADDA could not be run or failed; the message quotes ADDA and the command."""


class AddaNotFoundError(AddaError):
    """No ADDA binary where holofit looked."""


class AddaConvergenceError(AddaError):
    """ADDA's iterative solver hit ``-maxiter`` (ADDA itself only warns and exits 0)."""


class AddaWarning(UserWarning):
    """A non-fatal ADDA message, or an untested ADDA version."""


class AddaFarFieldWarning(AddaWarning):
    """The ADDA engine only knows far-field amplitudes; holograms use exp(ikr)/(-ikr) F."""
