"""A field of view described in a TOML file: which particles, how they move, what films them.

``holofit simulate field-of-view SCENE.toml`` reads it::

    instrument = "paper_60x_water"     # a name or a file
    frames = 500
    shape = [256, 320]                 # rows, columns of the frames
    temperature_c = 21.0               # for diffusion coefficients left out (spheres)
    seed = 1

    [[particle]]
    config = "sphere_ps_1um"           # a particle config: a name, or a file (beside the scene)
    start_um = [8.0, 9.0, 15.0]        # full-frame x, y, z at frame 0
    drift_um_s = [2.0, 0.0, 0.0]       # optional: a particle that crosses the field
    d_par_um2_s = 0.44                 # optional for spheres (Stokes-Einstein at temperature_c)
    d_perp_um2_s = 0.44
    d_r_s = 1.3
    alpha = 1.0                        # optional
    start_orientation = [0.0, 1.2, 0.0]  # optional: psi, theta, phi in rad

Each particle's trajectory is Brownian (:func:`holofit.simulate.brownian.simulate_trajectory`,
its own seed) and the holograms are superposed as fields
(:func:`holofit.simulate.field_of_view.simulate_field_of_view`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from holofit.analysis.hydrodynamics import sphere_diffusion
from holofit.config import Instrument, load_instrument, load_particle, resolve_config
from holofit.config_schema import ConfigError, Spec, read_toml, validate_table
from holofit.particles import Sphere
from holofit.simulate.brownian import BrownianParameters, simulate_trajectory
from holofit.simulate.field_of_view import ParticleInView

__all__ = ["Scene", "load_scene"]

SCENE_SPECS = {
    "instrument": Spec("str", "an instrument config (name or file)"),
    "frames": Spec("int", "the number of frames", 2, 1_000_000),
    "shape": Spec("lengths", "[rows, columns] of the frames", 16, 100_000),
    "temperature_c": Spec("float", "the temperature in C", -20.0, 150.0, required=False,
                          default=21.0),
    "seed": Spec("int", "a random seed", 0, 2**32 - 1, required=False, default=0),
    "noise": Spec("bool", "camera noise on or off", required=False, default=True),
}
PARTICLE_SPECS = {
    "config": Spec("str", "a particle config (name or file)"),
    "start_um": Spec("vector3", "the full-frame position at frame 0 in um"),
    "drift_um_s": Spec("vector3", "a drift velocity in um/s", required=False,
                       default=(0.0, 0.0, 0.0)),
    "d_par_um2_s": Spec("float", "D along the axis in um^2/s", 0.0, 1e3, required=False),
    "d_perp_um2_s": Spec("float", "D across the axis in um^2/s", 0.0, 1e3, required=False),
    "d_r_s": Spec("float", "the rotational D in 1/s", 0.0, 1e4, required=False),
    "alpha": Spec("float", "the scattered-field scaling", 0.0, 10.0, required=False,
                  default=1.0),
    "start_orientation": Spec("vector3", "[psi, theta, phi] in rad", required=False),
}


@dataclass
class Scene:
    """A field of view ready to simulate: the instrument, the frames, the particles."""

    instrument: Instrument
    n_frames: int
    frame_shape: tuple[int, int]
    particles: list[ParticleInView]
    seed: int
    noise: bool
    source: Path


def _diffusion(entry: dict[str, Any], model: Any, temperature_c: float, where: str,
               path: Path) -> tuple[float, float, float]:
    keys = ("d_par_um2_s", "d_perp_um2_s", "d_r_s")
    given = [entry[k] for k in keys]
    if all(v is not None for v in given):
        return tuple(float(v) for v in given)  # type: ignore[return-value]
    if isinstance(model, Sphere):
        d = sphere_diffusion(model.radius_um, temperature_c)
        return tuple(float(v) if v is not None else default for v, default in
                     zip(given, (d["D_t"], d["D_t"], d["D_r"]), strict=True))  # type: ignore
    missing = [k for k, v in zip(keys, given, strict=True) if v is None]
    raise ConfigError(f"{path}: [{where}] needs {', '.join(missing)} (only a sphere's are "
                      "computed, from Stokes-Einstein at temperature_c)")


def _particle(entry: Any, index: int, scene: dict[str, Any], inst: Instrument, path: Path
              ) -> ParticleInView:
    where = f"particle {index}"
    if not isinstance(entry, dict):
        raise ConfigError(f"{path}: [[particle]] number {index} is not a table")
    p = validate_table(entry, PARTICLE_SPECS, path, where)
    beside = path.parent / p["config"]  # a config file named beside the scene
    cfg = load_particle(beside if beside.is_file() else resolve_config(p["config"], "particles"))
    d_par, d_perp, d_r = _diffusion(p, cfg.model, scene["temperature_c"], where, path)
    dt = 1.0 / inst.frame_rate_hz if inst.frame_rate_hz else 1.0
    params = BrownianParameters(
        n_frames=scene["frames"], frame_interval_s=dt, d_par_um2_s=d_par, d_perp_um2_s=d_perp,
        d_r_s=d_r, drift_um_s=p["drift_um_s"], start_position_um=p["start_um"],
        start_orientation=p["start_orientation"])
    truth = simulate_trajectory(params, seed=scene["seed"] * 1000 + index).truth
    return ParticleInView(
        cfg.model, truth[["x_um", "y_um", "z_um"]].to_numpy(),
        truth[["psi_rad", "theta_rad", "phi_rad"]].to_numpy(), alpha=p["alpha"],
        theory=cfg.theory())


def load_scene(path: str | Path) -> Scene:
    """Read and check a scene file, and draw each particle's trajectory.

    Raises
    ------
    ConfigError
        A missing or misspelled key, a value out of range, no ``[[particle]]``, or a particle
        whose diffusion coefficients cannot be computed; the message names the file and the
        particle.
    """
    path = Path(path)
    raw = read_toml(path)
    entries = raw.pop("particle", None)
    scene = validate_table(raw, SCENE_SPECS, path, "scene")
    if len(scene["shape"]) != 2 or any(v != int(v) for v in scene["shape"]):
        raise ConfigError(f"{path}: [scene] key 'shape': expected [rows, columns] as two "
                          f"integers, got {list(scene['shape'])}")
    if not isinstance(entries, list) or not entries:
        raise ConfigError(f"{path}: no [[particle]] tables: a scene needs at least one particle")
    inst = load_instrument(resolve_config(scene["instrument"], "instruments"))
    particles = [_particle(e, i, scene, inst, path) for i, e in enumerate(entries)]
    shape = (int(scene["shape"][0]), int(scene["shape"][1]))
    return Scene(inst, scene["frames"], shape, particles, scene["seed"], scene["noise"], path)


def scene_positions_px(scene: Scene) -> np.ndarray:
    """Every particle's (x, y) per frame in pixels, shape (particles, frames, 2)."""
    return np.stack([np.asarray(p.positions_um)[:, :2] / scene.instrument.pixel_size_um
                     for p in scene.particles])
