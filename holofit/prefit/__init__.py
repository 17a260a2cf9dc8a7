"""The Lorenz-Mie prefit (step 2 of the paper's procedure): x, y, z, radius, index and alpha of
every crop from an automatic start, as the starting point of the DDA stages.

- :mod:`~holofit.prefit.profile`, :mod:`~holofit.prefit.estimate`: z, radius, index and alpha
  from the crop's radial profile, with no manual guess;
- :mod:`~holofit.prefit.sphere`: one crop, start to finish (:func:`fit_sphere_crop`);
- :mod:`~holofit.prefit.stage`: the ``holofit prefit`` stage over a crop folder
  (:func:`run_prefit`);
- :mod:`~holofit.prefit.plots`: ``prefit.png``.
"""

from holofit.prefit.estimate import ProfileStart, SearchSpace, estimate_starts
from holofit.prefit.sphere import SPHERE_COLUMNS, SphereFitSettings, fit_sphere_crop
from holofit.prefit.stage import PREFIT_COLUMNS, PrefitConfig, prefit_frame, run_prefit

__all__ = [
    "PREFIT_COLUMNS",
    "SPHERE_COLUMNS",
    "PrefitConfig",
    "ProfileStart",
    "SearchSpace",
    "SphereFitSettings",
    "estimate_starts",
    "fit_sphere_crop",
    "prefit_frame",
    "run_prefit",
]
