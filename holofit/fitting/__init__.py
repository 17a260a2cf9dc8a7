"""Fitting holograms: the Lorenz-Mie prefit of every crop, its automatic initial guesses, and
the residual / Jacobian / statistics helpers that the DDA fit reuses.

- :mod:`~holofit.fitting.crops`: read a crop folder (crops, table, instrument).
- :mod:`~holofit.fitting.profile`, :mod:`~holofit.fitting.estimate`: z, radius, index and alpha
  from the radial profile, with no manual guess.
- :mod:`~holofit.fitting.pixels`: which pixels a fit uses (NaN / saturation mask, random
  subset) and where they are.
- :mod:`~holofit.fitting.mie_pixels`, :mod:`~holofit.fitting.residuals`: the exact hologram on
  any set of pixels, residuals and Jacobian.
- :mod:`~holofit.fitting.sphere_fit`: one crop, start to finish.
- :mod:`~holofit.fitting.statistics`: uncertainties, noise estimate.
- :mod:`~holofit.fitting.prefit`: the ``holofit prefit`` stage over a whole crop folder.
"""

from holofit.fitting.crops import CropSet, CropSetError, open_crops
from holofit.fitting.estimate import ProfileStart, SearchSpace, estimate_starts
from holofit.fitting.pixels import PixelSelection, select_pixels
from holofit.fitting.prefit import PrefitConfig, prefit_frame, run_prefit
from holofit.fitting.residuals import SPHERE_PARAMETERS, SphereResiduals
from holofit.fitting.sphere_fit import FitOptions, SphereFit, fit_sphere_crop

__all__ = [
    "SPHERE_PARAMETERS",
    "CropSet",
    "CropSetError",
    "FitOptions",
    "PixelSelection",
    "PrefitConfig",
    "ProfileStart",
    "SearchSpace",
    "SphereFit",
    "SphereResiduals",
    "estimate_starts",
    "fit_sphere_crop",
    "open_crops",
    "prefit_frame",
    "run_prefit",
    "select_pixels",
]
