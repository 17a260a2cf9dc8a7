"""The prefit table (``prefit.csv``): its columns and units.

Written by :func:`holofit.prefit.stage.run_prefit` through the stage skeleton
(:func:`holofit.batch.stage.run_stage`: the batch runner writes the CSV and its sidecar
atomically, with :func:`prefit_columns` and :data:`PREFIT_UNITS`); one row per frame, the
fit-table schema (:mod:`holofit.tables.fit`) plus the prefit's own columns. Read back by the
library and fit stages through :func:`holofit.tables.inputs.read_stage_table`.
"""

from __future__ import annotations

from holofit.holomodel.parameters import APERTURE
from holofit.holomodel.result import result_columns
from holofit.status import FIT_STATUS_MEANINGS, describe
from holofit.tables.fit import column_unit

__all__ = ["PREFIT_COLUMNS", "PREFIT_UNITS", "SPHERE_FIT_COLUMNS", "SPHERE_START_COLUMNS",
           "prefit_columns"]

#: the sphere's fitted parameters (:data:`holofit.prefit.sphere.SPHERE_COLUMNS`)
SPHERE_FIT_COLUMNS: tuple[str, ...] = ("x_um", "y_um", "z_um", "radius_um", "n", "alpha")
#: the automatic start of each frame (:data:`holofit.prefit.sphere.START_COLUMNS`)
SPHERE_START_COLUMNS: tuple[str, ...] = ("n_starts", "start_z_um", "start_radius_um",
                                         "start_n", "start_alpha")


def prefit_columns(fit_na: bool = False) -> tuple[str, ...]:
    """Columns of ``prefit.csv``, in order (with ``numerical_aperture`` if it is fitted)."""
    fitted = (*SPHERE_FIT_COLUMNS, *((APERTURE.name,) if fit_na else ()))
    return result_columns(fitted, fitted,
                          ("crop_status", "n_masked", *SPHERE_START_COLUMNS, "setup_time_s"))


#: columns of ``prefit.csv``, in order (the NA held)
PREFIT_COLUMNS: tuple[str, ...] = prefit_columns()

_EXTRA_UNITS = {
    "time_s": "s (time of the frame: frame / the instrument's frame rate; NaN if unknown)",
    "status": describe(FIT_STATUS_MEANINGS),
    "crop_status": "status in the crop table",
    "n_masked": "count (pixels left out: NaN or saturated)",
    "n_starts": "count (candidate starts fitted)",
    "start_z_um": "um (automatic start)",
    "start_radius_um": "um (automatic start)",
    "start_n": "1 (automatic start)",
    "start_alpha": "1 (automatic start)",
    "setup_time_s": "s (one-time set-up paid by this frame in its worker: the estimator's table)",
    APERTURE.name: "1 (the objective's numerical aperture, fitted)",
    f"d_{APERTURE.name}": "1 (1-sigma uncertainty of numerical_aperture)",
}
#: unit of every column of ``prefit.csv``
PREFIT_UNITS: dict[str, str] = {c: _EXTRA_UNITS.get(c, column_unit(c))
                                for c in prefit_columns(fit_na=True)}
