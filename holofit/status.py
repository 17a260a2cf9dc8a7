"""The status words of holofit's per-frame tables, defined once.

Crop table (``crops.csv``): whether a frame has a hologram to fit. Fit tables (``prefit.csv``,
``fit.csv`` and anything :mod:`holofit.tables.fit` reads): how the fit of a frame ended.
"""

from __future__ import annotations

__all__ = [
    "CROP_EDGE",
    "CROP_ERROR",
    "CROP_NO_PARTICLE",
    "CROP_OFF_TRACK",
    "CROP_OK",
    "CROP_STATUSES",
    "CROP_STATUS_MEANINGS",
    "ERROR",
    "FAILED",
    "FAILED_STATUSES",
    "FITTABLE_CROP_STATUSES",
    "FIT_STATUSES",
    "FIT_STATUS_MEANINGS",
    "NOT_CONVERGED",
    "OK",
    "OVERLAP",
    "POOR_FIT",
    "SKIPPED",
    "describe",
]

# -- crop table ---------------------------------------------------------------------------
CROP_OK = "ok"
CROP_EDGE = "edge"
CROP_NO_PARTICLE = "no_particle"
CROP_ERROR = "error"
CROP_OFF_TRACK = "off_track"
CROP_STATUS_MEANINGS: dict[str, str] = {
    CROP_OK: "hologram found and cropped",
    CROP_EDGE: "hologram found; the crop was shifted to stay inside the frame",
    CROP_NO_PARTICLE: "no hologram found (all-NaN crop)",
    CROP_OFF_TRACK: "hologram found and cropped, but away from the movie's main track (another "
                    "particle taking over, or a false detection): not fitted",
    CROP_ERROR: "the frame could not be read or normalised (all-NaN crop)",
}
CROP_STATUSES: tuple[str, ...] = tuple(CROP_STATUS_MEANINGS)
#: crop statuses whose crops are fitted (the others become ``skipped`` fit rows)
FITTABLE_CROP_STATUSES: tuple[str, ...] = (CROP_OK, CROP_EDGE)

# -- fit tables ---------------------------------------------------------------------------
OK = "ok"
POOR_FIT = "poor_fit"
FAILED = "failed"
ERROR = "error"
NOT_CONVERGED = "not_converged"
SKIPPED = "skipped"
OVERLAP = "overlap"
FIT_STATUS_MEANINGS: dict[str, str] = {
    OK: "converged fit, close to the data and physical",
    POOR_FIT: "converged, but far from the data or outside the physical range (message says)",
    FAILED: "the fit diverged or is unusable",
    ERROR: "the fit raised an exception (message says which)",
    NOT_CONVERGED: "the fit hit its iteration limit",
    SKIPPED: "no hologram to fit (e.g. the crop stage found no particle)",
    OVERLAP: "another track's hologram overlaps the crop (crop table: overlap) and the fit "
             "is not ok: left out of the analysis",
}
FIT_STATUSES: tuple[str, ...] = tuple(FIT_STATUS_MEANINGS)
#: statuses that ``--retry-failed`` runs again
FAILED_STATUSES: tuple[str, ...] = (ERROR, NOT_CONVERGED)


def describe(meanings: dict[str, str]) -> str:
    """``"ok (converged fit) | failed (...) | ..."`` for a sidecar's units entry."""
    return " | ".join(f"{k} ({v})" for k, v in meanings.items())
