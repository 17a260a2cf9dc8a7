"""What a short movie's set-up spends (issue 26): the initial pass's and the library's DDA
solves in single precision unless the particle's ``[dda]`` table chooses, and what that does to
a fitted hologram (nothing at the noise level: checked against double-precision solves)."""

from __future__ import annotations

import numpy as np

from holofit.config import ParticleConfig, load_instrument, resolve_config
from holofit.conventions import DetectorGrid
from holofit.dda.engine import BuiltinDDA
from holofit.dda.settings import DDASettings
from holofit.fit.initial_pass import INITIAL_PRECISION, initial_particle
from holofit.hologram import calc_hologram
from holofit.library.stage import LIBRARY_PRECISION, LibraryConfig, new_library
from holofit.particles import JanusSphere, Sphere
from holofit.scattering.theory import Orientation

JANUS = JanusSphere(0.2, 0.05, 1.58, 2.7)


def _config(dda: dict | None) -> ParticleConfig:
    return ParticleConfig(JANUS, {} if dda is None else {"dda": dda}, "janus.toml")


def test_initial_pass_solves_in_single_precision_unless_the_config_says():
    got = initial_particle(_config({"dipole_size_um": 0.05}))
    assert got.dda_settings().precision == INITIAL_PRECISION == "single"
    assert got.dda_settings().dipole_size_um == 0.05  # the rest of the table kept
    explicit = _config({"dipole_size_um": 0.05, "precision": "double"})
    assert initial_particle(explicit) is explicit
    sphere = ParticleConfig(Sphere(0.5, 1.59), {}, "s.toml")
    assert initial_particle(sphere) is sphere


def test_library_solves_in_single_precision_unless_the_config_says():
    inst = load_instrument(resolve_config("paper_100x_oil", "instruments"))
    # the DDA's library (auto would give a Janus particle its exact T-matrix)
    dda = {"dipole_size_um": 0.05, "engine": "builtin"}
    lib = new_library(LibraryConfig(_config(dda), inst))
    assert lib.theory.settings.precision == LIBRARY_PRECISION == "single"
    lib = new_library(LibraryConfig(_config({**dda, "precision": "double"}), inst))
    assert lib.theory.settings.precision == "double"


def test_single_precision_solves_change_a_hologram_far_below_camera_noise():
    """A Janus particle's hologram from single- and double-precision solves at the solver's
    default tolerance: the difference is below 1e-5 of the hologram's modulation (an 8-bit
    camera's quantum alone is 4e-3 of the background)."""
    inst = load_instrument(resolve_config("paper_100x_oil", "instruments"))
    grid = DetectorGrid((64, 64), 0.106)
    pos = (3.4, 3.4, 6.0)
    holos = []
    for precision in ("double", "single"):
        engine = BuiltinDDA(DDASettings(dipole_size_um=0.05, precision=precision))
        wave = engine.solve(JANUS, inst.optics, Orientation(0.4, 1.1, 0.0))
        holos.append(calc_hologram(wave, pos, grid))
    modulation = np.ptp(holos[0])
    assert np.abs(holos[1] - holos[0]).max() < 1e-5 * modulation


def test_a_short_initial_pass_is_cut_in_two():
    """4 initial frames (``--initial-frames 4``): two chunks of 2 (one per worker of 2 cores,
    the initial pass's chunks never overlap), not one of 4; 8 frames and more in chunks of at
    least 4."""
    from holofit.fit.chunks import INITIAL_OVERLAP, initial_min_chunk, plan_chunks

    def plan(n):
        return plan_chunks(list(range(n)), INITIAL_OVERLAP, min_chunk=initial_min_chunk(n))

    assert plan(3) == [[0, 1, 2]]
    assert plan(4) == [[0, 1], [2, 3]]
    assert plan(7) == [[0, 1, 2, 3], [4, 5, 6]]
    assert plan(8) == [[0, 1, 2, 3], [4, 5, 6, 7]]
    assert plan(10) == [[0, 1, 2, 3, 4], [5, 6, 7, 8, 9]]
    assert len(plan(100)) == 8 and min(len(c) for c in plan(100)) >= 4
