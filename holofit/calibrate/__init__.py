"""Instrument calibration on spheres: the objective's numerical aperture, its spherical
aberration and the polarisation, shared by many sphere holograms whose own parameters are free
(:mod:`holofit.calibrate.joint`), and the stage that fits them to a movie's crops and writes
the calibrated instrument file (:mod:`holofit.calibrate.stage`, ``holofit calibrate``)."""

from holofit.calibrate.config import CalibrateConfig, CalibrateError, CalibrationRun
from holofit.calibrate.joint import (
    InstrumentFit,
    JointFitSettings,
    SphereFrame,
    calibrate_instrument,
)
from holofit.calibrate.stage import run_calibrate

__all__ = ["CalibrateConfig", "CalibrateError", "CalibrationRun", "InstrumentFit",
           "JointFitSettings", "SphereFrame", "calibrate_instrument", "run_calibrate"]
