"""Crop-stage speed: the centre finder on a full camera frame, and a long movie end to end.

- ``centerfind_1024x1280_s``: :func:`holofit.crop.find_centers` on one normalised 1024 x 1280
  frame holding two Lorenz-Mie holograms with camera noise (target <= 0.1 s on one core;
  pylorenzmie's FFT circle transform takes ~0.32 s on this machine type);
  ``centerfind_1024x1280_cpu_s`` the same call's median CPU time (on shared cores the wall
  time follows the load, the CPU time much less).
- ``normalize_1024x1280_s``: background division of one raw frame.
- ``crop_frames_per_s``: :func:`holofit.crop.run_crop` on a 200-frame 1024 x 1280 8-bit movie
  (read, normalise, find, crop, write), plot off.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np
from timing import median_time

from holofit.camera import Camera
from holofit.config import load_instrument, resolve_config
from holofit.conventions import DetectorGrid, hologram_intensity
from holofit.crop import CropConfig, find_centers, normalize, run_crop
from holofit.io.tiffstack import TiffStackWriter
from holofit.particles import Sphere
from holofit.scattering.mie import LorenzMie

SHAPE = (1024, 1280)
CAMERA = Camera(bit_depth=8, background_counts=120.0, read_noise_counts=0.8)


def _instrument():
    return load_instrument(resolve_config("paper_60x_water", "instruments"))


def _two_particle_frame(rng: np.random.Generator) -> np.ndarray:
    inst = _instrument()
    px = inst.pixel_size_um
    grid = DetectorGrid(SHAPE, px)
    ex = np.zeros(SHAPE, complex)
    ey = np.zeros(SHAPE, complex)
    for sphere, (x, y, z) in [
        (Sphere(0.5, 1.45), (400.3 * px, 300.7 * px, 12.0)),
        (Sphere(0.8, 1.59), (900.6 * px, 650.2 * px, 18.0)),
    ]:
        fx, fy = LorenzMie().solve(sphere, inst.optics).field_on_detector((x, y, z), grid)
        ex += fx
        ey += fy
    return CAMERA.expose(hologram_intensity(ex, ey, inst.polarization_rad), rng)


def _patch_hologram(half: int = 200) -> np.ndarray:
    inst = _instrument()
    px = inst.pixel_size_um
    grid = DetectorGrid((2 * half + 1, 2 * half + 1), px)
    wave = LorenzMie().solve(Sphere(0.5, 1.45), inst.optics)
    ex, ey = wave.field_on_detector((half * px, half * px, 15.0), grid)
    return hologram_intensity(ex, ey, inst.polarization_rad)


def _median_cpu(fn, repeat: int = 20) -> float:
    """Median CPU time of ``fn()`` in seconds (this process), after one untimed call."""
    fn()
    times = []
    for _ in range(repeat):
        t0 = time.process_time()
        fn()
        times.append(time.process_time() - t0)
    return float(np.median(times))


def bench_centerfind() -> dict[str, float]:
    rng = np.random.default_rng(0)
    raw = _two_particle_frame(rng)
    background = np.full(SHAPE, CAMERA.background_counts)
    image, mask = normalize(raw, background)
    found = find_centers(image, mask=mask)
    assert len(found) == 2, found
    t_find = median_time(lambda: find_centers(image, mask=mask), repeat=20)
    cpu_find = _median_cpu(lambda: find_centers(image, mask=mask), repeat=20)
    t_norm = median_time(lambda: normalize(raw, background), repeat=20)
    return {"centerfind_1024x1280_s": t_find, "centerfind_1024x1280_cpu_s": cpu_find,
            "normalize_1024x1280_s": t_norm}


def bench_crop_movie(n_frames: int = 200) -> dict[str, float]:
    rng = np.random.default_rng(1)
    patch = _patch_hologram()
    half = patch.shape[0] // 2
    with tempfile.TemporaryDirectory(prefix="holofit-bench-crop-") as tmp:
        folder = Path(tmp)
        centre = np.array([500.0, 600.0])
        with TiffStackWriter(folder / "movie.tif") as writer:
            for _ in range(n_frames):
                centre += rng.normal(0, 2.0, 2)
                i, j = np.round(centre).astype(int)
                frame = np.ones(SHAPE)
                frame[i - half : i + half + 1, j - half : j + half + 1] = patch
                writer.write(CAMERA.expose(frame, rng))
        with TiffStackWriter(folder / "background.tif") as writer:
            for _ in range(5):
                writer.write(CAMERA.expose(np.ones(SHAPE), rng))
        t0 = time.perf_counter()
        result = run_crop(folder / "movie.tif", folder / "background.tif", _instrument(),
                          folder / "out", CropConfig(plot=False))
        elapsed = time.perf_counter() - t0
        assert result.counts["ok"] == n_frames, result.counts
    return {"crop_frames_per_s": n_frames / elapsed, "crop_movie_frames": float(n_frames)}


BENCHMARKS = {"centerfind": bench_centerfind, "crop_movie": bench_crop_movie}
