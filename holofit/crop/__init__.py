"""The crop stage: normalise raw frames by the background, find hologram centres with a
Hough-type (orientation-alignment) transform refined to sub-pixel precision by point symmetry
(by circular symmetry near the frame's edge), and crop N x N around them.

Library entry points:

- :func:`run_crop`: the whole stage on a movie, its settings a :class:`CropConfig` (frames
  searched through the stage skeleton, in parallel and resumably, then cropped in frame
  order; writes ``crops.tif``, ``crops.csv`` + sidecar, ``candidates.csv``, ``crops.png``:
  :mod:`holofit.tables.crop`);
- :func:`find_centers`: ranked centres of one normalised image;
- :func:`normalize`: one raw frame -> normalised image and mask.
"""

from holofit.crop.centerfind import CenterFinder, find_centers
from holofit.crop.errors import CropError, FrameError
from holofit.crop.normalize import Normalizer, normalize
from holofit.crop.settings import CropConfig
from holofit.crop.stage import CropResult, run_crop
from holofit.tables.crop import CROP_COLUMNS, CROP_UNITS

__all__ = [
    "CROP_COLUMNS",
    "CROP_UNITS",
    "CenterFinder",
    "CropConfig",
    "CropError",
    "CropResult",
    "FrameError",
    "Normalizer",
    "find_centers",
    "normalize",
    "run_crop",
]
