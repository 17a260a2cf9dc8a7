"""What the fit-stage tests share: a serial batch and a small rod's particle config."""

from __future__ import annotations

from holofit.batch import BatchOptions

SERIAL = BatchOptions(workers=0, progress=False)
#: a small rod with a coarse lattice: a cheap DDA for stage tests
ROD_TOML = """
[particle]
model = "spherocylinder"
a_um = 0.3
b_um = 0.7
index = 1.5

[dda]
dipole_size_um = 0.1
"""
