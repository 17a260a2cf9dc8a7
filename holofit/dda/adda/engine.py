"""ADDA as an alternative scattering engine (``--engine adda``).

Per evaluation the engine

1. discretises the model with holofit's own voxeliser (binary, centre-inside voxels, the same
   dipoles the built-in engine uses with ``filling="binary"``) and writes them as an ADDA shape
   file, in ADDA's particle frame (:mod:`holofit.dda.adda.files`);
2. writes the scattering directions of the detector pixels as an ADDA ``pairs`` file;
3. runs ADDA in a private temporary directory (:mod:`holofit.dda.adda.run`) with
   ``-shape read``, ``-m`` (indices relative to the medium), ``-lambda`` (wavelength in the
   medium), ``-size``, ``-orient``, ``-scat_grid_inp``, ``-store_scat_grid``,
   ``-scat_matr ampl``, ``-eps``, ``-maxiter``, ``-dir``;
4. reads ``ampl_scatgrid`` by row order (the printed angles are rounded to 0.01 deg and only
   used as a check), builds the far-field vector for the instrument's polarisation from
   S1..S4, moves the phase origin from ADDA's dipole-box centre to the particle centre and
   maps ADDA's lab frame onto holofit's (:mod:`holofit.dda.adda.frames`).

ADDA returns far-field amplitudes only, so :class:`AddaWave` always uses the asymptotic form
``E_sca(r n) = exp(ikr)/(-ikr) F(n)`` (as the paper did); ``exact_near_field`` is False, the
wave's :attr:`AddaWave.description` says so, and asking it for the exact field warns once with
:class:`~holofit.dda.adda.errors.AddaFarFieldWarning`.
"""

from __future__ import annotations

import os
import shlex
import shutil
import tempfile
import warnings
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from holofit.cache import LRUCache
from holofit.conventions import euler_zyz
from holofit.dda.adda.binary import adda_version, find_adda
from holofit.dda.adda.errors import AddaError, AddaFarFieldWarning, AddaWarning
from holofit.dda.adda.files import (
    AddaGeometry,
    adda_geometry,
    read_ampl_scatgrid,
    read_cross_sections,
    write_geometry,
    write_pairs_file,
)
from holofit.dda.adda.frames import (
    adda_orientation_deg,
    far_field_from_ampl,
    lab_map,
    lab_to_adda_angles,
)
from holofit.dda.adda.run import AddaResult, adda_command, run_adda
from holofit.dda.lattice import Lattice
from holofit.dda.settings import DDASettings
from holofit.dda.voxelize import voxelize
from holofit.optics import Optics
from holofit.particles import ParticleModel
from holofit.scattering.theory import Orientation, ScatteredWave, ScatteringEngine

__all__ = ["AddaEngine", "AddaWave"]


def _tail(text: str, lines: int = 5) -> str:
    """The last lines ADDA printed, quoted, or ``nothing``."""
    kept = [line.strip() for line in text.strip().splitlines() if line.strip()][-lines:]
    return " | ".join(kept).join("''") if kept else "nothing"


class AddaWave(ScatteredWave):
    """A particle, orientation and illumination for ADDA; ADDA runs when fields are asked for.

    Every new set of directions (a new particle position or detector) is one ADDA run; the last
    few are cached. Fields always use the far-field form ``exp(ikr)/(-ikr) F(n)``.
    """

    exact_near_field = False

    def __init__(self, engine: AddaEngine, model: ParticleModel, optics: Optics,
                 orientation: Orientation, geometry: AddaGeometry) -> None:
        self.engine = engine
        self.model = model
        self.optics = optics
        self.orientation = orientation
        self.geometry = geometry
        self.rotation = euler_zyz(*orientation.as_tuple())
        self.lab = lab_map(optics.polarization_rad)
        self.orient_deg = adda_orientation_deg(orientation, optics.polarization_rad)
        self.last_run: AddaResult | None = None
        self._cache: LRUCache[tuple, NDArray[np.complex128]] = LRUCache(4)
        self._warned = False

    @property
    def description(self) -> str:
        """What this wave's fields are (for logs and sidecars)."""
        return (f"ADDA {self.engine.version.version} far-field amplitudes; scattered field "
                "E = exp(ikr)/(-ikr) F(r_hat) (far-field form, no near-field terms, as in "
                "Wang et al. 2014)")

    @property
    def metadata(self) -> dict[str, Any]:
        """Engine facts for provenance sidecars."""
        return {
            "engine": "adda",
            "adda_binary": self.engine.binary,
            "adda_version": self.engine.version.version,
            "adda_commit": self.engine.version.commit,
            "field": "far-field: exp(ikr)/(-ikr) F(r_hat)",
            "dipole_size_um": self.geometry.d,
            "n_dipoles": self.geometry.n_dipoles,
            "adda_orient_deg": list(self.orient_deg),
            "adda_lab_from_holofit_lab": self.lab.tolist(),
            "last_command": shlex.join(self.last_run.command) if self.last_run else None,
        }

    def amplitude_matrix(self, directions: ArrayLike) -> NDArray[np.complex128]:
        """ADDA's ``[S1, S2, S3, S4]`` (M, 4) at holofit-lab directions, ADDA's basis and
        phase origin (the raw numbers of one run)."""
        return self._run(np.atleast_2d(np.asarray(directions, dtype=float)))[0]

    def far_field_amplitude(self, directions: ArrayLike) -> NDArray[np.complex128]:
        """``F(n)`` (M, 3) in holofit's lab for the instrument's polarisation, phase origin at
        the particle centre: ``E_sca = exp(ikr)/(-ikr) F`` (same as the built-in engine's)."""
        n = np.atleast_2d(np.asarray(directions, dtype=float))
        n = n / np.linalg.norm(n, axis=1, keepdims=True)
        key = (n.shape, hash(n.tobytes()))
        cached = self._cache.get(key)
        if cached is not None:
            return cached
        s, theta, phi = self._run(n)
        f = far_field_from_ampl(s, theta, phi, n, self.optics, self.rotation,
                                self.geometry.centre_offset_um, self.lab)
        return self._cache.put(key, f)

    def _run(self, n: NDArray[np.float64]) -> tuple[NDArray, NDArray, NDArray]:
        theta, phi = lab_to_adda_angles(n, self.lab)
        result = self.engine.run(self.geometry, self.optics, self.orient_deg, theta, phi)
        self.last_run = result
        assert result.ampl is not None
        return result.ampl, theta, phi

    def field_at(self, points_um: ArrayLike, far_field: bool = False) -> NDArray[np.complex128]:
        """Scattered field at lab points (relative to the particle centre), far-field form
        always (``far_field=False`` warns once: ADDA has no near field)."""
        if not far_field and not self._warned:
            warnings.warn(
                "ADDA engine: " + self.description + "; the exact near field is not available",
                AddaFarFieldWarning, stacklevel=3,
            )
            self._warned = True
        pts = np.atleast_2d(np.asarray(points_um, dtype=float))
        r = np.linalg.norm(pts, axis=1)
        f = self.far_field_amplitude(pts / r[:, None])
        k = self.optics.k
        return f * (np.exp(1j * k * r) / (-1j * k * r))[:, None]


class AddaEngine(ScatteringEngine):
    """Scattering by the user's ADDA binary, behind holofit's scattering-theory interface.

    Parameters
    ----------
    adda_path : str or Path, optional
        The binary (else ``HOLOFIT_ADDA``, else ``adda`` on PATH); see :func:`find_adda`.
    settings : DDASettings, optional
        Dipole size (or dipoles per wavelength), tolerance, iteration limit and polarisability
        (``ldr`` or ``cm``), shared with the built-in engine. ``filling`` is ignored: ADDA gets
        binary (centre-inside) voxels.
    timeout_s : float, optional
        Wall-time limit of one ADDA run (default one hour).
    keep_files : bool
        Keep each run's temporary directory (its path is in ``wave.last_run.workdir``).
    **options
        Overrides of ``settings`` fields (``dipole_size_um=``, ``tolerance=`` ...).

    Raises
    ------
    AddaNotFoundError
        If no binary is found (at construction, so that ``--engine adda`` fails early).
    """

    name = "adda"

    def __init__(self, adda_path: str | os.PathLike[str] | None = None,
                 settings: DDASettings | None = None, timeout_s: float | None = 3600.0,
                 keep_files: bool = False, **options: Any) -> None:
        base = settings or DDASettings()
        self.settings = base.replace(**options) if options else base
        if adda_path is None:
            adda_path = getattr(self.settings, "adda_path", None)
        self.binary = str(find_adda(adda_path))
        self.version = adda_version(self.binary)
        self.timeout_s = timeout_s
        self.keep_files = keep_files
        self._geometries: LRUCache[tuple, AddaGeometry] = LRUCache(16)
        self.runs = 0

    def dipole_size(self, model: ParticleModel, optics: Optics) -> float:
        """The lattice spacing this engine uses for ``model``, um."""
        return self.settings.dipole_size_for(model, optics)

    def lattice(self, model: ParticleModel, optics: Optics) -> Lattice:
        """The binary discretisation of ``model`` (the built-in engine's with filling=binary)."""
        return voxelize(model, self.dipole_size(model, optics), "binary")

    def geometry(self, model: ParticleModel, optics: Optics) -> AddaGeometry:
        """The dipoles ADDA gets for ``model`` (cached)."""
        key = (model, self.dipole_size(model, optics))
        return self._geometries.get_or_create(
            key, lambda: adda_geometry(self.lattice(model, optics)))

    def solve(self, model: ParticleModel, optics: Optics,
              orientation: Orientation | None = None) -> AddaWave:
        return AddaWave(self, model, optics, orientation or Orientation(),
                        self.geometry(model, optics))

    def run(self, geometry: AddaGeometry, optics: Optics, orient_deg: tuple[float, float, float],
            theta_deg: NDArray[np.float64], phi_deg: NDArray[np.float64]) -> AddaResult:
        """One ADDA run in a private temporary directory; reads and checks ``ampl_scatgrid``."""
        tmp = Path(tempfile.mkdtemp(prefix="holofit-adda-"))
        try:
            write_geometry(tmp / "shape.dat", geometry)
            write_pairs_file(tmp / "pairs.dat", theta_deg, phi_deg)
            args = adda_command(
                geometry, optics, orient_deg, "shape.dat", "pairs.dat", "out",
                tolerance=self.settings.tolerance, max_iterations=self.settings.max_iterations,
                polarizability=self.settings.polarizability,
            )
            result = run_adda(self.binary, args, tmp, self.timeout_s)
            self.runs += 1
            out = tmp / "out"
            try:
                result.ampl = read_ampl_scatgrid(out / "ampl_scatgrid", theta_deg, phi_deg)
            except AddaError as exc:
                # the work folder is deleted: name the file as ADDA's -dir names it
                text = str(exc).replace(f"{tmp}{os.sep}", "")
                raise AddaError(
                    f"ADDA ran (exit status 0) but its output is unusable: {text}; ADDA printed "
                    f"{_tail(result.stdout + result.stderr)}\n"
                    f"command: {shlex.join(result.command)}"
                ) from None
            result.cross_sections = {pol: read_cross_sections(out / f"CrossSec-{pol}")
                                     for pol in ("X", "Y")}
            log = out / "log"
            result.log = log.read_text(errors="replace") if log.exists() else ""
            for message in result.warnings:
                warnings.warn(f"ADDA: {message}", AddaWarning, stacklevel=4)
            if not self.keep_files:
                result.workdir = None
            return result
        finally:
            if not self.keep_files:
                shutil.rmtree(tmp, ignore_errors=True)
