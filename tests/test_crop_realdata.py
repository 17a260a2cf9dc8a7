"""Centres of measured holograms against the published fits (issue 5, Must show).

Reference centres, converted to holofit's (x = column, y = row) pixels:

- HoloPy ``image0001`` (x_holopy = row): Lorenz-Mie fit (5.534, 5.792) um / 0.1151 um ->
  column 50.32, row 48.08; HoloPy's own Hough finder: row 48.573, column 50.232.
- HoloPy ``image01`` with ``bg01..03`` and ``df01``: tutorial fit (24.16, 21.84) um / 0.0851
  -> column 256.64, row 283.90.
- pylorenzmie ``PS_silica`` (x = column): PS (376.437, 481.864), silica (907.701, 484.8).
- pylorenzmie ``image0400``: (582.514, 686.094) and (883.809, 747.796).
- pylorenzmie ``sample`` with ``background`` (dark count 13): lower-left sphere re-fit
  (321.72, 733.46); the upper-right object has no reliable fit (about (921, 303)).
"""

from __future__ import annotations

import numpy as np
import pytest
import tifffile

from holofit.crop import find_centers, normalize
from holofit.crop.reference import read_reference_frame
from tests.conftest import DATA

HOLOPY = DATA / "holopy"
PYLM = DATA / "pylorenzmie"
TOLERANCE_PX = 1.5


def _match(found, reference):
    """Distance from each reference centre to the nearest found centre."""
    xy = found[["x_px", "y_px"]].to_numpy()
    return [float(np.min(np.hypot(*(xy - np.asarray(ref)).T))) for ref in reference]


def _report(name, found, reference):
    dist = _match(found, reference)
    print(
        f"\n{name}: "
        + "; ".join(f"{ref} -> {d:.2f} px" for ref, d in zip(reference, dist, strict=True))
    )
    return dist


def test_holopy_image0001():
    raw = tifffile.imread(HOLOPY / "image0001.tif")
    # already background-divided (scaled so max = 255): the background level is its mean
    image, mask = normalize(raw, np.full(raw.shape, raw.mean()))
    found = find_centers(image, mask=mask, radius_px=40)
    assert len(found) == 1
    fit = (5.792 / 0.1151, 5.534 / 0.1151)  # HoloPy (x=row, y=col) -> (col, row)
    holopy_finder = (50.23217416, 48.5729142)
    dist = _report("image0001", found, [fit, holopy_finder])
    assert max(dist) <= TOLERANCE_PX


def test_holopy_image01_with_background_and_dark():
    raw = tifffile.imread(HOLOPY / "image01.tif")
    bgs = np.stack([tifffile.imread(HOLOPY / f"bg0{k}.tif") for k in (1, 2, 3)])
    background = np.median(bgs.astype(float), axis=0)
    dark = tifffile.imread(HOLOPY / "df01.tif")
    image, mask = normalize(raw, background, dark)
    found = find_centers(image, mask=mask)
    assert len(found) == 1  # the dust near the upper-right corner is not a hologram
    dist = _report("image01", found, [(21.84 / 0.0851, 24.16 / 0.0851)])
    assert dist[0] <= TOLERANCE_PX


@pytest.mark.parametrize(
    "name,reference",
    [
        ("PS_silica", [(376.437, 481.864), (907.701, 484.8)]),
        ("image0400", [(582.514, 686.094), (883.809, 747.796)]),
    ],
)
def test_pylorenzmie_normalised_frames(name, reference):
    raw = tifffile.imread(PYLM / f"{name}.tif")
    # stored normalised with the background at 100 counts; 255 is saturated
    image, mask = normalize(raw, np.full(raw.shape, 100.0), saturation=255)
    found = find_centers(image, mask=mask)
    assert len(found) == 2
    dist = _report(name, found, reference)
    assert max(dist) <= TOLERANCE_PX


def test_pylorenzmie_sample_raw_with_background_and_dark_count():
    raw = tifffile.imread(PYLM / "sample.tif")
    background = read_reference_frame(PYLM / "background.tif")
    image, mask = normalize(raw, background, 13)
    assert float(np.nanmean(image)) == pytest.approx(1.0025, abs=0.003)  # README's mean
    found = find_centers(image, mask=mask)
    assert len(found) == 2  # no dust rings or artefacts
    dist = _report("sample", found, [(321.72, 733.46), (921.0, 303.3)])
    assert dist[0] <= TOLERANCE_PX
    assert dist[1] <= 3.0  # approximate reference position only
