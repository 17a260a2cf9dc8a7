"""holofit: fast, exact holographic tracking of non-spherical colloids.

The public API, by job (the command line is a thin layer over these functions)::

    stages         run_crop, run_prefit, run_calibrate, run_library, run_fit, run_analysis
                   (BatchSettings, CalibrateConfig, LibrarySettings, FitConfig, FrameFitSettings,
                   FollowSettings, ContinuitySettings, AnalysisConfig, TrackSelection)
    simulation     simulate_movie, simulate_trajectory, BrownianParameters
    configuration  Instrument, load_instrument, ParticleConfig, load_particle, DDASettings
    particles      Sphere, Spherocylinder, JanusSphere, Dimer, Spheroid, Ellipsoid, Cylinder,
                   CoatedSphere, Cluster, VoxelShape
    geometry       Orientation, DetectorGrid, Optics
    engines        LorenzMie, BuiltinDDA, AddaEngine, ClusterEngine, CoatedMie, select_engine,
                   get_engine
    holograms      hologram, calc_hologram
    fitting        HologramModel, ParameterSpace, solve_least_squares, FitResult,
                   QualityLimits, fit_sphere_crop, FrameProblem, fit_frame, fit_frame_warm,
                   evaluate_frame
    tables         read_fit_table, write_fit_table

Names are imported on first use (``holofit.run_crop`` loads the crop stage only), so that
``import holofit`` stays cheap and a Lorenz-Mie user never compiles the DDA kernels.

Example::

    import holofit
    inst = holofit.load_instrument("configs/instruments/paper_60x_water.toml")
    holofit.run_crop("movie.tif", "background.tif", inst, "crop/")
    holofit.run_prefit("crop/", "prefit/")
"""

from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.1.0"

#: public name -> module that defines it
_API: dict[str, str] = {
    # stages
    "run_crop": "holofit.crop.stage",
    "run_prefit": "holofit.prefit.stage",
    "run_calibrate": "holofit.calibrate.stage",
    "CalibrateConfig": "holofit.calibrate.config",
    "run_library": "holofit.library.stage",
    "LibrarySettings": "holofit.library.stage",
    "run_fit": "holofit.fit.stage",
    "FitConfig": "holofit.fit.config",
    "FrameFitSettings": "holofit.fit.settings",
    "FollowSettings": "holofit.fit.settings",
    "ContinuitySettings": "holofit.fit.continuity",
    "run_analysis": "holofit.analysis",
    "BatchSettings": "holofit.batch.runner",
    "BatchOptions": "holofit.batch.options",
    "AnalysisConfig": "holofit.analysis",
    "TrackSelection": "holofit.analysis",
    # simulation
    "simulate_movie": "holofit.simulate.holograms",
    "simulate_trajectory": "holofit.simulate.brownian",
    "BrownianParameters": "holofit.simulate.brownian",
    # configuration
    "Instrument": "holofit.config",
    "load_instrument": "holofit.config",
    "ParticleConfig": "holofit.config",
    "load_particle": "holofit.config",
    "DDASettings": "holofit.dda.settings",
    # particle models
    "Sphere": "holofit.particles",
    "Spherocylinder": "holofit.particles",
    "JanusSphere": "holofit.particles",
    "Dimer": "holofit.particles",
    "Spheroid": "holofit.particles",
    "Ellipsoid": "holofit.particles",
    "Cylinder": "holofit.particles",
    "CoatedSphere": "holofit.particles",
    "Cluster": "holofit.particles",
    "VoxelShape": "holofit.particles",
    # geometry and light
    "Orientation": "holofit.scattering.theory",
    "DetectorGrid": "holofit.conventions",
    "Optics": "holofit.optics",
    # engines
    "LorenzMie": "holofit.scattering.mie",
    "BuiltinDDA": "holofit.dda.engine",
    "AddaEngine": "holofit.dda.adda.engine",
    "ClusterEngine": "holofit.scattering.cluster",
    "CoatedMie": "holofit.scattering.coated_mie",
    "select_engine": "holofit.engines.select",
    "get_engine": "holofit.engines.registry",
    # holograms
    "hologram": "holofit.hologram",
    "calc_hologram": "holofit.hologram",
    # fitting kit
    "HologramModel": "holofit.holomodel.forward",
    "ParameterSpace": "holofit.holomodel.parameters",
    "solve_least_squares": "holofit.holomodel.leastsq",
    "FitResult": "holofit.holomodel.result",
    "QualityLimits": "holofit.quality",
    "fit_sphere_crop": "holofit.prefit.sphere",
    "FrameProblem": "holofit.fit.problem",
    "fit_frame": "holofit.fit.frame",
    "fit_frame_warm": "holofit.fit.warm",
    "evaluate_frame": "holofit.fit.warm",
    # tables
    "read_fit_table": "holofit.tables.fit",
    "write_fit_table": "holofit.tables.fit",
}

__all__ = ["__version__", *_API]


def __getattr__(name: str) -> Any:
    module = _API.get(name)
    if module is None:
        raise AttributeError(f"module 'holofit' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(__all__)
