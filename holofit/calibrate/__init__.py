"""Instrument calibration on spheres: the objective's numerical aperture, its spherical
aberration and the polarisation, shared by many sphere holograms whose own parameters are free
(:mod:`holofit.calibrate.joint`)."""

from holofit.calibrate.joint import (
    InstrumentFit,
    JointFitSettings,
    SphereFrame,
    calibrate_instrument,
)

__all__ = ["InstrumentFit", "JointFitSettings", "SphereFrame", "calibrate_instrument"]
