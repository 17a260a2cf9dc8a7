"""The library's tilts solved once for every worker (``library/tilts.npz``).

Every worker of the library stage needs the same solved tilts (:class:`OrientationLibrary`:
two DDA solves per tilt), which take far longer than scoring a frame: solved by each worker on
its own, a short movie's library costs as much on 8 workers as on one. So, where the stage
runs on local worker processes, the driver has the tilts solved once, shared out in
contiguous blocks (neighbouring tilts warm-start each other's solves) over as many processes,
and writes their scattered waves as outgoing multipole expansions (lab frame, about the
particle centre) to ``OUT/tilts.npz``; the workers read them instead of solving. The camera
sees a solved particle only through that expansion (the lens images it:
:mod:`holofit.scattering.lens_sources`; without a lens the camera plane lies far outside the
near zone), so the scores are those of the workers' own solves.

An engine whose waves have no such expansion (ADDA) keeps the workers' own solves.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from holofit.io.atomic import atomic_path
from holofit.scattering.expansion_wave import ExpansionWave
from holofit.scattering.multipole import MultipoleExpansion
from holofit.scattering.theory import ScatteredWave

if TYPE_CHECKING:  # pragma: no cover
    from holofit.library.search import OrientationLibrary

__all__ = ["TILTS_FILE", "load_tilts", "solve_tilts"]

#: the solved tilts in the library's output folder
TILTS_FILE = "tilts.npz"


def _blocks(n: int, parts: int) -> list[list[int]]:
    """``range(n)`` cut into ``parts`` contiguous blocks of nearly equal size."""
    size = math.ceil(n / max(parts, 1))
    return [list(range(s, min(s + size, n))) for s in range(0, n, size)]


def _solve_block(make: Any, indices: Sequence[int]) -> list[tuple[Any, ...]] | None:
    """Solve tilts ``indices`` of the library ``make()`` gives; their expansions (None where
    the engine's waves have none)."""
    lib = make()
    out = []
    for i in indices:
        pair = lib.waves(i)
        expansions = [getattr(w, "expansion", None) for w in pair]
        present = [e for e in expansions if e is not None]
        if len(present) != len(expansions):
            return None
        out.append((i, *((e.k, e.p, e.q, e.radius_um) for e in present)))
    return out


def solve_tilts(make: Any, key: str, n_tilts: int, workers: int, path: Path) -> Path | None:
    """Solve the ``n_tilts`` tilts of the library ``make()`` returns (a picklable callable)
    on ``workers`` spawned processes and write their expansions to ``path`` (atomically);
    ``path``, or None where the engine's waves have no expansion.

    ``key`` (the library's configuration fingerprint) is stored with them: :func:`load_tilts`
    uses the file only for the same configuration.
    """
    import concurrent.futures as cf
    import multiprocessing

    blocks = _blocks(n_tilts, workers)
    with cf.ProcessPoolExecutor(max_workers=len(blocks),
                                mp_context=multiprocessing.get_context("spawn")) as pool:
        parts = list(pool.map(_solve_block, [make] * len(blocks), blocks))
    solved = [p for p in parts if p is not None]
    if len(solved) != len(parts):
        return None
    rows = sorted((r for p in solved for r in p), key=lambda r: r[0])
    arrays: dict[str, Any] = {"key": np.array(key), "n_tilts": np.array(n_tilts)}
    for i, *pair in rows:
        for pol, (k, p, q, radius) in zip("xy", pair, strict=True):
            arrays[f"t{i}_{pol}_p"], arrays[f"t{i}_{pol}_q"] = p, q
            arrays[f"t{i}_{pol}_kr"] = np.array([k, radius])
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        np.savez(fh, **arrays)
    return path


def load_tilts(lib: OrientationLibrary, path: Path, key: str) -> bool:
    """Give ``lib`` the solved tilts of ``path`` (True), unless it is missing or was made for
    another configuration or tilt grid (False: ``lib`` solves them itself)."""
    try:
        data = np.load(path)
    except (OSError, ValueError):
        return False
    with data:
        if str(data["key"]) != key or int(data["n_tilts"]) != len(lib.tilts):
            return False
        for i in range(len(lib.tilts)):
            pair: list[ScatteredWave] = []
            for pol, optics in (("x", lib.optics_x), ("y", lib.optics_y)):
                k, radius = data[f"t{i}_{pol}_kr"]
                exp = MultipoleExpansion(float(k), data[f"t{i}_{pol}_p"],
                                         data[f"t{i}_{pol}_q"], float(radius))
                pair.append(ExpansionWave(optics, exp))
            lib.set_waves(i, (pair[0], pair[1]))
    return True
