"""What the fit-stage tests share: a serial batch, a small rod's particle config, and a
simulated movie taken through crop, prefit and library."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from holofit.batch import BatchSettings

SERIAL = BatchSettings(workers=0, progress=False)
#: a small rod with a coarse lattice: a cheap DDA for stage tests (the config names the
#: built-in DDA: ``auto`` would give a rod its exact T-matrix)
ROD_TOML = """
[particle]
model = "spherocylinder"
a_um = 0.3
b_um = 0.7
index = 1.5

[dda]
dipole_size_um = 0.1
engine = "builtin"
"""


def crop_prefit_library(sim: Any, inst: Any, particle: Any, root: Path) -> None:
    """``sim`` (a simulated movie) through crop (64-pixel crops), prefit and the library of
    ``particle`` (15 deg tilts) into ``root``'s ``crop``, ``prefit`` and ``lib``, serially."""
    from holofit.crop import CropConfig, run_crop
    from holofit.library.stage import LibrarySettings, run_library
    from holofit.prefit import run_prefit

    run_crop(sim.movie, sim.background, inst, root / "crop", CropConfig(size=64, plot=False))
    run_prefit(root / "crop", root / "prefit", batch=SERIAL, plot=False)
    run_library(root / "crop", root / "prefit", particle, root / "lib",
                settings=LibrarySettings(tilt_step_deg=15, n_phi=64, n_candidates=2),
                batch=SERIAL, plot=False)
