"""The resolvable separation of two identical particles, per instrument (issue 36).

Two identical particles at the same height, ``d`` apart along a random direction, filmed by
the instrument's simulated camera (:func:`holofit.simulate.holograms.default_camera`: shot,
read and quantisation noise); the crop stage's default centre finder (the instrument's fringe
limits; vote radius half the default crop side, which the crop chooses from the movie's
holograms: the larger of 140 px and four zone radii, :func:`holofit.crop.settings.
sized_for_movie`; here the median zone radius of the holograms the default finder finds in
five draws of the pair 10 um apart at that height, as the crop's preview does) searches
every noise draw. A draw resolves the pair when both particles have a detection within
:data:`TOLERANCE_UM` of their centre and no other detection lies within ``d + 1 um`` of the
pair's midpoint. The *resolvable separation* is the smallest ``d`` of the grid from which on
every larger ``d`` resolves the pair in at least 95 % of the draws.

Particles: the 1 um polystyrene sphere (``sphere_ps_1um``) and the paper's rod (``rod_paper``,
its DDA T-matrix; the two rods at independent random orientations) at heights
:data:`HEIGHTS_UM`; instruments ``paper_60x_water``, ``paper_100x_oil`` and ``pylorenzmie``.
The holograms are superposed as fields (noise-free once per geometry, then exposed per draw).

Usage: ``python bench/resolvable_separation.py OUT.json [DRAWS [INSTRUMENT ...]]``; writes one
flat JSON object (``<instrument>_<particle>_z<height>_resolvable_um`` and the resolved
fraction at every separation).
"""

from __future__ import annotations

import json
import math
import sys
import time
import zlib
from typing import Any

import numpy as np

from holofit.config import Instrument, load_instrument, load_particle, resolve_config
from holofit.conventions import hologram_intensity, pixel_centres
from holofit.crop.settings import (
    SIZE_PREVIEW_FRAMES,
    CropConfig,
    crop_size_for_zone,
    hologram_zones,
)
from holofit.scattering.recorded_field import recorded_field
from holofit.scattering.theory import Orientation
from holofit.simulate.holograms import default_camera

INSTRUMENTS = ("paper_60x_water", "paper_100x_oil", "pylorenzmie")
SEPARATIONS_UM = (1.5, 2.0, 2.5, 3.0, 3.5, 4.0, 5.0, 6.0, 8.0, 10.0)
HEIGHTS_UM = {"sphere": (12.0, 20.0), "rod": (12.0,)}
#: a particle is detected within this distance of its centre, um
TOLERANCE_UM = 0.5
#: frames span this many um a side (most of the holograms' reach at 12-20 um)
FRAME_UM = 32.0


def _frame_shape(inst: Instrument) -> tuple[int, int]:
    n = int(math.ceil(FRAME_UM / inst.pixel_size_um / 16.0) * 16)
    return (n, n)


class _Pairs:
    """Noise-free holograms of a pair on one instrument, and noisy frames of them."""

    def __init__(self, inst: Instrument, particle: str) -> None:
        self.inst = inst
        cfg = load_particle(resolve_config(
            "sphere_ps_1um" if particle == "sphere" else "rod_paper", "particles"))
        self.model = cfg.model
        self.theory = cfg.theory(fixed_lattice_for=inst.optics)
        if self.model.anisotropic:
            self.theory.tmatrix(self.model, inst.optics)
        self.shape = _frame_shape(inst)
        xs, ys = pixel_centres(self.shape, inst.pixel_size_um)
        self.xs, self.ys = xs.ravel(), ys.ravel()
        self.camera = default_camera(inst)

    def intensity(self, d_um: float, z_um: float, rng: np.random.Generator
                  ) -> tuple[np.ndarray, list[tuple[float, float]]]:
        px = self.inst.pixel_size_um
        cx = (self.shape[1] / 2 + rng.uniform(-0.5, 0.5)) * px
        cy = (self.shape[0] / 2 + rng.uniform(-0.5, 0.5)) * px
        angle = rng.uniform(0, np.pi)
        dx, dy = 0.5 * d_um * np.cos(angle), 0.5 * d_um * np.sin(angle)
        ex = np.zeros(self.xs.size, complex)
        ey = np.zeros(self.xs.size, complex)
        truth = []
        for sign in (-1, 1):
            x, y = cx + sign * dx, cy + sign * dy
            o = (Orientation(rng.uniform(0, 2 * np.pi), np.arccos(rng.uniform(-1, 1)), 0.0)
                 if self.model.anisotropic else Orientation(0.0, 0.0, 0.0))
            wave = self.theory.solve(self.model, self.inst.optics, o)
            fx, fy = recorded_field(wave, (x, y, z_um), self.xs, self.ys)
            ex += fx
            ey += fy
            truth.append((x / px, y / px))
        image = hologram_intensity(ex.reshape(self.shape), ey.reshape(self.shape),
                                   self.inst.optics.polarization_rad)
        return image, truth

    def frame(self, image: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        return self.camera.expose(image, rng).astype(np.float64) / self.camera.background_counts


def resolved(found: Any, truth: list[tuple[float, float]], d_um: float, px: float) -> bool:
    """Both detected within the tolerance, nothing else near the pair."""
    xy = found[["x_px", "y_px"]].to_numpy()
    if len(xy) < 2:
        return False
    tol = TOLERANCE_UM / px
    hits = [np.hypot(xy[:, 0] - x, xy[:, 1] - y) < tol for x, y in truth]
    if not all(h.any() for h in hits):
        return False
    mx, my = np.mean(truth, axis=0)
    near = np.hypot(xy[:, 0] - mx, xy[:, 1] - my) < (d_um + 1.0) / px
    return int(near.sum()) == 2


def resolvable(fractions: dict[float, float], required: float = 0.95) -> float:
    """Smallest separation from which on every larger one resolves ``required``."""
    best = math.nan
    for d in sorted(fractions, reverse=True):
        if fractions[d] < required:
            break
        best = d
    return best


def default_finder(pairs: _Pairs, z_um: float, rng: np.random.Generator) -> tuple[Any, float]:
    """The crop stage's default finder for a movie of pairs at ``z_um``: its side from the
    zone radii the 140-px default measures on a few frames (as the crop's preview does)."""
    probe = CropConfig().finder_for_size(pairs.inst)
    zones = []
    for _ in range(SIZE_PREVIEW_FRAMES):
        image, _ = pairs.intensity(max(SEPARATIONS_UM), z_um, rng)
        zones += hologram_zones(probe.find(pairs.frame(image, rng)))
    zone = float(np.median(zones)) if zones else math.nan
    side = crop_size_for_zone(zone, pairs.shape)
    return CropConfig(size=side).finder_for_size(pairs.inst), zone


def run(draws: int, instruments: tuple[str, ...]) -> dict[str, Any]:
    out: dict[str, Any] = {"draws": draws, "tolerance_um": TOLERANCE_UM}
    for name in instruments:
        inst = load_instrument(resolve_config(name, "instruments"))
        out[f"{name}_frame_px"] = _frame_shape(inst)[0]
        for particle, heights in HEIGHTS_UM.items():
            t0 = time.time()
            pairs = _Pairs(inst, particle)
            for z in heights:
                rng = np.random.default_rng(zlib.crc32(f"{name}/{particle}/{z:g}".encode()))
                finder, zone = default_finder(pairs, z, rng)
                out[f"{name}_{particle}_z{z:g}_zone_px"] = round(zone, 1)
                out[f"{name}_{particle}_z{z:g}_vote_radius_px"] = finder.radius_px
                fractions = {}
                for d in SEPARATIONS_UM:
                    ok = 0
                    for _ in range(draws):
                        image, truth = pairs.intensity(d, z, rng)
                        found = finder.find(pairs.frame(image, rng))
                        ok += resolved(found, truth, d, inst.pixel_size_um)
                    fractions[d] = ok / draws
                    out[f"{name}_{particle}_z{z:g}_d{d:g}"] = round(fractions[d], 3)
                out[f"{name}_{particle}_z{z:g}_resolvable_um"] = resolvable(fractions)
                print(name, particle, z, f"zone {zone:.1f} px, vote radius "
                      f"{finder.radius_px:g} px", fractions, flush=True)
            out[f"{name}_{particle}_time_s"] = round(time.time() - t0, 1)
    return out


if __name__ == "__main__":
    draws = int(sys.argv[2]) if len(sys.argv) > 2 else 20
    names = tuple(sys.argv[3:]) or INSTRUMENTS
    result = run(draws, names)
    with open(sys.argv[1], "w") as fh:
        json.dump(result, fh, indent=1)
        fh.write("\n")
    print(json.dumps(result, indent=1))
