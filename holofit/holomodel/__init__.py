"""The hologram model kit shared by the prefit and the DDA fit: one forward model, one least-squares
entry point, one result type.

- :mod:`~holofit.holomodel.pixels`: which pixels a fit uses (NaN / saturation mask, random
  subset) and where they are;
- :mod:`~holofit.holomodel.parameters`: named parameters (units, finite-difference steps,
  physical ranges) and the map from the optimiser's vector to a particle state;
- :mod:`~holofit.holomodel.forward`: :class:`HologramModel`, parameters -> hologram on the pixels
  and its Jacobian, for any scattering engine, with a cache of solved waves;
- :mod:`~holofit.holomodel.leastsq`: :func:`solve_least_squares` (Levenberg-Marquardt);
- :mod:`~holofit.holomodel.result`: :class:`FitResult`, its status and its table row;
- :mod:`~holofit.holomodel.statistics`: uncertainties, pixel-noise estimate;
- :mod:`~holofit.holomodel.plots`: parameter plots and data / model / residual images.
"""

from holofit.holomodel.forward import HologramModel, InvalidParameters
from holofit.holomodel.leastsq import Solution, solve_least_squares
from holofit.holomodel.parameters import Parameter, ParameterSpace, State
from holofit.holomodel.pixels import PixelSelection, select_pixels
from holofit.holomodel.result import FitResult, fit_result, result_row
from holofit.quality import QualityLimits

__all__ = [
    "FitResult",
    "HologramModel",
    "InvalidParameters",
    "Parameter",
    "ParameterSpace",
    "PixelSelection",
    "QualityLimits",
    "Solution",
    "State",
    "fit_result",
    "result_row",
    "select_pixels",
    "solve_least_squares",
]
