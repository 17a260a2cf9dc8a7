"""ADDA as an alternative scattering engine (``--engine adda``).

holofit never contains ADDA: it drives the user's own ``adda`` binary (found through an
explicit path, the ``HOLOFIT_ADDA`` environment variable or ``PATH``) as a second
implementation of :class:`~holofit.scattering.theory.ScatteringTheory`. Per evaluation it

1. discretises the model with holofit's own voxeliser (binary, centre-inside voxels, the same
   dipoles the built-in engine uses with ``filling="binary"``) and writes them as an ADDA shape
   file, in ADDA's particle frame;
2. writes the scattering directions of the detector pixels as an ADDA ``pairs`` file;
3. runs ADDA in a private temporary directory with ``-shape read``, ``-m`` (indices relative to
   the medium), ``-lambda`` (wavelength in the medium), ``-size``, ``-orient``, ``-scat_grid_inp``,
   ``-store_scat_grid``, ``-scat_matr ampl``, ``-eps``, ``-maxiter``, ``-dir``;
4. reads ``ampl_scatgrid`` by row order (the printed angles are rounded to 0.01 deg and only
   used as a check), builds the far-field vector for the instrument's polarisation from
   S1..S4, moves the phase origin from ADDA's dipole-box centre to the particle centre and
   maps ADDA's lab frame onto holofit's.

Frames (the seams this module owns)
-----------------------------------
holofit's lab has the light travelling along -z; ADDA's along +z. The rotation
``T = Rx(pi) = diag(1, -1, -1)`` maps one onto the other (x stays, y and z flip). ADDA always
solves two incident polarisations, along its lab x ("X") and y ("Y"), with the LDR
polarisability of each; holofit puts the instrument's polarisation on ADDA's x, so that ADDA's
X solution is exactly the instrument's: holofit lab -> ADDA lab is ``M = T Rz(-beta)``
(:func:`lab_map`, ``M = T`` for x polarisation), with beta the polarisation angle.

ADDA is given the dipoles in holofit's particle frame flipped by ``T`` (``y -> -y``,
``z -> -z``), so that its particle-to-lab rotation is ``R_adda = M R T``, with
``R = Rz(psi) Ry(theta) Rz(phi)`` holofit's; for x polarisation ``T R T = Rz(-psi) Ry(-theta)
Rz(-phi)``. ``-orient`` gets the zyz angles of ``R_adda`` (beta in [0, 180] deg). A Janus
particle at holofit's theta = 0 (cap toward the source) has its cap toward ADDA's -z.

ADDA refers the incident phase and ``F(n)`` to the centre of its dipole box. With ``s`` the
particle centre relative to that point (lab frame) and ``a`` the propagation direction,
``F_centre(n) = F_adda(n) exp(-i k (a - n).s)`` (both frames give the same dot product).

Field at the detector
---------------------
ADDA returns far-field amplitudes only, so :class:`AddaWave` always uses the asymptotic form
``E_sca(r n) = exp(ikr)/(-ikr) F(n)`` (as the paper did); ``exact_near_field`` is False, the
wave's :attr:`AddaWave.description` says so, and asking it for the exact field warns once with
:class:`AddaFarFieldWarning`.
"""

from __future__ import annotations

import functools
import math
import os
import re
import shlex
import shutil
import subprocess
import tempfile
import time
import warnings
from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from holofit.conventions import PROPAGATION_DIRECTION, euler_zyz, rotation_z
from holofit.dda.lattice import Lattice
from holofit.dda.settings import DDASettings
from holofit.dda.voxelize import voxelize
from holofit.models import ParticleModel
from holofit.optics import Optics
from holofit.scattering.registry import ENGINES
from holofit.scattering.theory import Orientation, ScatteredWave, ScatteringTheory

__all__ = [
    "ADDA_ENV_VAR",
    "TESTED_VERSIONS",
    "T_LAB",
    "AddaConvergenceError",
    "AddaEngine",
    "AddaError",
    "AddaFarFieldWarning",
    "AddaGeometry",
    "AddaNotFoundError",
    "AddaResult",
    "AddaVersion",
    "AddaWarning",
    "AddaWave",
    "adda_command",
    "adda_geometry",
    "adda_orientation_deg",
    "adda_version",
    "amplitude_vectors",
    "check_adda_output",
    "far_field_from_ampl",
    "find_adda",
    "lab_map",
    "lab_to_adda_angles",
    "parse_version",
    "phase_origin_factor",
    "read_ampl_scatgrid",
    "run_adda",
    "write_pairs_file",
    "write_shape_file",
    "zyz_angles",
]

#: environment variable naming the ADDA binary
ADDA_ENV_VAR = "HOLOFIT_ADDA"
#: executable name looked up on PATH
ADDA_BINARY_NAME = "adda"
#: ADDA versions whose flags, file formats and conventions were verified against holofit
TESTED_VERSIONS = ("1.5.0-alpha3",)
#: oldest version with the behaviour the adapter relies on (``-maxiter`` only warns since 1.4)
MIN_VERSION = (1, 4)
#: holofit lab -> ADDA lab (and holofit particle frame -> ADDA particle frame): Rx(pi)
T_LAB = np.diag([1.0, -1.0, -1.0])
#: tolerance on the printed (%.2f) angles of ampl_scatgrid against the requested ones, deg
ANGLE_CHECK_DEG = 0.0051

_AMPL_HEADER = "theta phi s1.r s1.i s2.r s2.i s3.r s3.i s4.r s4.i".split()
_MAXITER_RE = re.compile(r"haven't converged in (\d+) iterations", re.IGNORECASE)


# -- errors and warnings ---------------------------------------------------------------------


class AddaError(RuntimeError):
    """ADDA could not be run or failed; the message quotes ADDA and the command."""


class AddaNotFoundError(AddaError):
    """No ADDA binary where holofit looked."""


class AddaConvergenceError(AddaError):
    """ADDA's iterative solver hit ``-maxiter`` (ADDA itself only warns and exits 0)."""


class AddaWarning(UserWarning):
    """A non-fatal ADDA message, or an untested ADDA version."""


class AddaFarFieldWarning(AddaWarning):
    """The ADDA engine only knows far-field amplitudes; holograms use exp(ikr)/(-ikr) F."""


# -- finding ADDA and its version ------------------------------------------------------------


def find_adda(adda_path: str | os.PathLike[str] | None = None) -> Path:
    """Locate the ADDA binary.

    Order: ``adda_path`` (argument or the config's ``adda_path``), then the environment variable
    ``HOLOFIT_ADDA``, then ``adda`` on ``PATH``. A value may be a path or a command name.

    Raises
    ------
    AddaNotFoundError
        Naming every place that was tried.
    """
    tried: list[str] = []
    candidates: list[tuple[str, str]] = []
    if adda_path is not None and str(adda_path) != "":
        candidates.append(("adda_path", str(adda_path)))
    env = os.environ.get(ADDA_ENV_VAR, "")
    if env:
        candidates.append((ADDA_ENV_VAR, env))
    for source, value in candidates:
        found = _executable(value)
        if found is None:
            raise AddaNotFoundError(
                f"ADDA binary given by {source} = {value!r} does not exist or is not executable"
            )
        return found
    tried.append(f"{ADDA_ENV_VAR} (unset)")
    found = shutil.which(ADDA_BINARY_NAME)
    if found is not None:
        return Path(found).resolve()
    tried.append(f"{ADDA_BINARY_NAME!r} on PATH (not found)")
    raise AddaNotFoundError(
        "no ADDA binary found; tried " + ", ".join(tried) + ". Build ADDA "
        "(https://github.com/adda-team/adda, `make seq` in src/) and set "
        f"{ADDA_ENV_VAR}=/path/to/adda, put `adda` on PATH, or give adda_path in the config."
    )


def _executable(value: str) -> Path | None:
    path = Path(value).expanduser()
    if path.is_file() and os.access(path, os.X_OK):
        return path.resolve()
    if os.sep not in value:
        found = shutil.which(value)
        if found is not None:
            return Path(found).resolve()
    return None


@dataclass(frozen=True)
class AddaVersion:
    """What ``adda -V`` says about a binary.

    Attributes
    ----------
    binary : str
        Resolved path of the binary.
    version : str
        Version string, e.g. ``"1.5.0-alpha3"``.
    commit : str
        Git hash in parentheses after the version, if printed.
    banner : str
        The first line of ``adda -V``.
    tested : bool
        True if ``version`` is in :data:`TESTED_VERSIONS`.
    """

    binary: str
    version: str
    commit: str
    banner: str
    tested: bool

    @property
    def numbers(self) -> tuple[int, ...]:
        """Leading numeric part of the version, e.g. (1, 5, 0)."""
        match = re.match(r"(\d+(?:\.\d+)*)", self.version)
        return tuple(int(v) for v in match.group(1).split(".")) if match else ()


_VERSION_RE = re.compile(r"ADDA\s+v\.?\s*(\d[^\s()]*)\s*(?:\(([^)]*)\))?")


def parse_version(text: str, binary: str = "adda") -> AddaVersion:
    """Parse the output of ``adda -V`` (first line ``ADDA v.1.5.0-alpha3 (acbebb0)``).

    Raises
    ------
    AddaError
        If the text does not look like ADDA's version banner.
    """
    for line in text.splitlines():
        match = _VERSION_RE.search(line)
        if match:
            version = match.group(1)
            return AddaVersion(binary=binary, version=version, commit=match.group(2) or "",
                               banner=line.strip(), tested=version in TESTED_VERSIONS)
    head = text.strip().splitlines()[:3]
    raise AddaError(f"{binary} -V did not print an ADDA version banner; it printed: {head!r}")


@functools.cache
def adda_version(binary: str) -> AddaVersion:
    """Version of the ADDA binary at ``binary``, checked once per process (cached).

    Warns (:class:`AddaWarning`) once if the version is not one holofit was tested with.
    """
    command = [binary, "-V"]
    try:
        proc = subprocess.run(command, capture_output=True, text=True, timeout=60,
                              stdin=subprocess.DEVNULL)
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise AddaError(f"could not run `{shlex.join(command)}`: {exc}") from exc
    if proc.returncode != 0:
        raise AddaError(
            f"`{shlex.join(command)}` exited with status {proc.returncode}: "
            f"{(proc.stderr or proc.stdout).strip()[-2000:]}"
        )
    info = parse_version(proc.stdout + "\n" + proc.stderr, binary)
    if not info.tested:
        note = ""
        if info.numbers and info.numbers[:2] < MIN_VERSION:
            note = (" Versions before 1.4 stop with an error at -maxiter and were never tried"
                    " with holofit.")
        warnings.warn(
            f"ADDA {info.version} at {binary} is not a version holofit was tested with "
            f"({', '.join(TESTED_VERSIONS)}); results are used as they come.{note}",
            AddaWarning, stacklevel=2,
        )
    return info


# -- frames and angles -----------------------------------------------------------------------


def zyz_angles(rotation: ArrayLike) -> tuple[float, float, float]:
    """zyz Euler angles ``(alpha, beta, gamma)`` (rad) of a rotation matrix.

    ``rotation = Rz(alpha) Ry(beta) Rz(gamma)`` with ``beta`` in [0, pi]; for ``beta`` = 0 or
    pi, ``gamma`` = 0.
    """
    r = np.asarray(rotation, dtype=float)
    beta = math.acos(min(1.0, max(-1.0, r[2, 2])))
    if math.sin(beta) > 1e-12:
        alpha = math.atan2(r[1, 2], r[0, 2])
        gamma = math.atan2(r[2, 1], -r[2, 0])
    elif r[2, 2] > 0:  # beta = 0: only alpha + gamma matters
        alpha, gamma = math.atan2(r[1, 0], r[0, 0]), 0.0
    else:  # beta = pi: only alpha - gamma matters
        alpha, gamma = math.atan2(-r[1, 0], r[1, 1]), 0.0
    return alpha, beta, gamma


def lab_map(polarization_rad: float = 0.0) -> NDArray[np.float64]:
    """Rotation from holofit's lab onto the ADDA lab used for an instrument polarisation.

    ``M = T Rz(-beta)``: the instrument's polarisation ``(cos beta, sin beta, 0)`` becomes ADDA's
    x (so ADDA's "X" solution is the instrument's, with the LDR polarisability of that very
    polarisation) and the light's -z becomes ADDA's +z. ``M = T`` for x polarisation.
    """
    return T_LAB @ rotation_z(-polarization_rad)


def adda_orientation_deg(
    orientation: Orientation | None, polarization_rad: float = 0.0
) -> tuple[float, float, float]:
    """``-orient`` angles (deg) for a holofit orientation.

    ADDA gets the dipoles in holofit's particle frame flipped by ``T``, so its particle-to-lab
    rotation is ``M R T`` (``M`` = :func:`lab_map`; ``T R T`` for x polarisation). Returned as
    zyz angles with beta in [0, 180] and alpha, gamma in (-180, 180].
    """
    rot = euler_zyz(*(orientation or Orientation()).as_tuple())
    r_adda = lab_map(polarization_rad) @ rot @ T_LAB
    return tuple(math.degrees(v) for v in zyz_angles(r_adda))  # type: ignore[return-value]


def lab_to_adda_angles(
    directions: ArrayLike, lab: ArrayLike = T_LAB
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """ADDA's scattering angles ``(theta, phi)`` (deg) of holofit-lab unit directions (M, 3).

    ``n_adda = lab @ n`` (``lab`` = :func:`lab_map`); ``theta`` in [0, 180] from ADDA's +z (the
    propagation direction), ``phi`` in [0, 360) from ADDA's x.
    """
    n = np.atleast_2d(np.asarray(directions, dtype=float)) @ np.asarray(lab, dtype=float).T
    n = n / np.linalg.norm(n, axis=1, keepdims=True)
    theta = np.degrees(np.arccos(np.clip(n[:, 2], -1.0, 1.0)))
    phi = np.degrees(np.arctan2(n[:, 1], n[:, 0])) % 360.0
    return theta, phi


def _adda_directions(theta_deg: ArrayLike, phi_deg: ArrayLike) -> NDArray[np.float64]:
    th, ph = np.radians(theta_deg), np.radians(phi_deg)
    return np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], axis=-1)


def amplitude_vectors(
    s: ArrayLike, theta_deg: ArrayLike, phi_deg: ArrayLike, polarization: ArrayLike
) -> NDArray[np.complex128]:
    """Far-field vectors ``F(n)`` (M, 3) in ADDA's lab from ADDA's amplitude matrix.

    ADDA's (Bohren & Huffman) basis at ``n(theta, phi)``: ``e_par_i = (cos phi, sin phi, 0)``,
    ``e_per_i = (sin phi, -cos phi, 0)``, ``e_par_s = e_theta``, ``e_per_s = -e_phi``, and
    ``[E_par_s, E_per_s] = [[S2, S3], [S4, S1]] [E_par_i, E_per_i]``. For an incident field
    ``e exp(ikz)`` (``e`` in ADDA's xy plane, any complex combination), ``E_par_i = e.e_par_i``,
    ``E_per_i = e.e_per_i`` and ``F = E_par_s e_theta - E_per_s e_phi`` with
    ``E_sca = exp(ikr)/(-ikr) F``.

    Parameters
    ----------
    s : array_like, shape (M, 4)
        ``[S1, S2, S3, S4]`` per direction.
    theta_deg, phi_deg : array_like, shape (M,)
        ADDA's scattering angles, deg (the exact requested ones, not the printed ones).
    polarization : array_like, shape (3,)
        Incident polarisation in ADDA's lab (z component ignored).
    """
    s = np.asarray(s, dtype=complex)
    th, ph = np.radians(theta_deg), np.radians(phi_deg)
    e = np.asarray(polarization, dtype=complex)
    c, sn = np.cos(ph), np.sin(ph)
    e_par_i = e[0] * c + e[1] * sn
    e_per_i = e[0] * sn - e[1] * c
    e_par_s = s[:, 1] * e_par_i + s[:, 2] * e_per_i
    e_per_s = s[:, 3] * e_par_i + s[:, 0] * e_per_i
    e_theta = np.stack([np.cos(th) * c, np.cos(th) * sn, -np.sin(th)], axis=-1)
    e_phi = np.stack([-sn, c, np.zeros_like(ph)], axis=-1)
    return e_par_s[:, None] * e_theta - e_per_s[:, None] * e_phi


def phase_origin_factor(
    directions: ArrayLike, centre_offset_um: ArrayLike, k: float,
    propagation: ArrayLike = PROPAGATION_DIRECTION,
) -> NDArray[np.complex128]:
    """Factor that refers ADDA's amplitudes to the particle centre.

    ``F_centre(n) = F_adda(n) * exp(-i k (a - n).s)``, with ``s`` the particle centre relative to
    ADDA's origin (the dipole-box centre) and ``a`` the propagation direction, all in one lab
    frame (holofit's by default).
    """
    n = np.atleast_2d(np.asarray(directions, dtype=float))
    a = np.asarray(propagation, dtype=float)
    s = np.asarray(centre_offset_um, dtype=float)
    return np.exp(-1j * k * ((a[None, :] - n) @ s))


# -- geometry --------------------------------------------------------------------------------


@dataclass(frozen=True)
class AddaGeometry:
    """A dipole set as ADDA reads it (ADDA's particle frame: holofit's flipped by T).

    Attributes
    ----------
    ijk : ndarray of int, shape (N, 3)
        Dipole indices, each axis starting at 0 (tight box).
    domain : ndarray of int, shape (N,)
        1-based material (domain) number of each dipole.
    n_domains : int
        Number of materials (``-m`` pairs given to ADDA).
    d : float
        Dipole size, um.
    box : tuple of int
        ``(nx, ny, nz)``: ADDA's box; ``-size`` is ``nx * d``.
    centre_offset_um : ndarray, shape (3,)
        Particle centre relative to the box centre (ADDA's phase origin), in *holofit's*
        particle frame, um.
    indices : tuple of complex
        Absolute refractive index of each domain.
    """

    ijk: NDArray[np.int64]
    domain: NDArray[np.int64]
    n_domains: int
    d: float
    box: tuple[int, int, int]
    centre_offset_um: NDArray[np.float64]
    indices: tuple[complex, ...]

    @property
    def n_dipoles(self) -> int:
        return int(self.ijk.shape[0])

    @property
    def size_um(self) -> float:
        """ADDA's ``-size``: the box length along x, um."""
        return self.box[0] * self.d

    def positions_adda(self) -> NDArray[np.float64]:
        """Dipole positions relative to the box centre, ADDA's particle frame, um."""
        return (self.ijk - (np.asarray(self.box) - 1) / 2.0) * self.d


def adda_geometry(lattice: Lattice, threshold: float = 0.5) -> AddaGeometry:
    """The dipoles of ``lattice`` that ADDA will see, in ADDA's (T-flipped) particle frame.

    A voxel is kept if its total material fraction is at least ``threshold`` (binary lattices:
    all); its domain is its dominant material. The box is re-tightened around the kept voxels,
    and the particle centre is located relative to that box's centre.
    """
    total = lattice.fractions.sum(axis=1)
    keep = total >= threshold
    if not np.any(keep):
        raise ValueError("ADDA engine: no voxel is filled enough to be written as a dipole")
    ijk = lattice.ijk[keep]
    domain = np.argmax(lattice.fractions[keep], axis=1) + 1
    lo, hi = ijk.min(axis=0), ijk.max(axis=0)
    # box centre of the kept voxels, holofit particle frame; particle centre relative to it
    box_centre = lattice.origin + lattice.d * (lo + hi) / 2.0
    flipped = np.column_stack([ijk[:, 0] - lo[0], hi[1] - ijk[:, 1], hi[2] - ijk[:, 2]])
    box = tuple(int(v) for v in hi - lo + 1)
    return AddaGeometry(
        ijk=flipped.astype(np.int64), domain=domain.astype(np.int64),
        n_domains=int(lattice.fractions.shape[1]), d=float(lattice.d),
        box=box,  # type: ignore[arg-type]
        centre_offset_um=-box_centre, indices=tuple(lattice.indices),
    )


def write_shape_file(path: str | Path, geometry: AddaGeometry) -> Path:
    """Write an ADDA text shape file (``ix iy iz [domain]``; ``Nmat=`` line if several)."""
    path = Path(path)
    lines = ["# holofit dipole set for ADDA (ADDA particle frame = holofit's flipped by Rx(pi))",
             f"# d = {geometry.d!r} um, box = {geometry.box}"]
    if geometry.n_domains > 1:
        lines.append(f"Nmat={geometry.n_domains}")
        body = np.column_stack([geometry.ijk, geometry.domain])
    else:
        body = geometry.ijk
    rows = [" ".join(map(str, row)) for row in body.tolist()]
    path.write_text("\n".join(lines + rows) + "\n")
    return path


def write_pairs_file(path: str | Path, theta_deg: ArrayLike, phi_deg: ArrayLike) -> Path:
    """Write ADDA's ``-scat_grid_inp`` file with ``global_type=pairs`` (full precision)."""
    th = np.asarray(theta_deg, dtype=float).ravel()
    ph = np.asarray(phi_deg, dtype=float).ravel()
    head = f"global_type=pairs\nN={th.size}\npairs=\n"
    body = "\n".join(f"{t!r} {p!r}" for t, p in zip(th.tolist(), ph.tolist(), strict=True))
    Path(path).write_text(head + body + "\n")
    return Path(path)


def read_ampl_scatgrid(
    path: str | Path,
    theta_deg: ArrayLike | None = None,
    phi_deg: ArrayLike | None = None,
) -> NDArray[np.complex128]:
    """Read ADDA's ``ampl_scatgrid``: the amplitude matrix ``[S1, S2, S3, S4]`` per row (M, 4).

    Rows are in the order of the requested directions (pairs: file order; grid: theta outer,
    phi inner). The printed angles are rounded (``%.2f``), so they are only compared with the
    requested ``theta_deg``, ``phi_deg`` (if given) to catch a row-order mismatch.

    Raises
    ------
    AddaError
        Wrong header, wrong number of rows, or printed angles that do not match.
    """
    path = Path(path)
    try:
        with path.open() as fh:
            header = fh.readline().split()
            data = np.loadtxt(fh, ndmin=2)
    except FileNotFoundError:
        raise AddaError(f"{path}: ADDA wrote no ampl_scatgrid") from None
    except ValueError as exc:
        raise AddaError(f"{path}: unreadable amplitude table: {exc}") from None
    if header != _AMPL_HEADER:
        raise AddaError(f"{path}: unexpected header {' '.join(header)!r}; expected "
                        f"{' '.join(_AMPL_HEADER)!r} (run with -scat_matr ampl)")
    if data.shape[1] != 10:
        raise AddaError(f"{path}: expected 10 columns, got {data.shape[1]}")
    if theta_deg is not None and phi_deg is not None:
        th = np.asarray(theta_deg, dtype=float).ravel()
        ph = np.asarray(phi_deg, dtype=float).ravel()
        if data.shape[0] != th.size:
            raise AddaError(f"{path}: {data.shape[0]} rows for {th.size} requested directions")
        d_th = np.abs(data[:, 0] - th)
        d_ph = np.abs((data[:, 1] - ph + 180.0) % 360.0 - 180.0)
        bad = np.nonzero((d_th > ANGLE_CHECK_DEG) | (d_ph > ANGLE_CHECK_DEG))[0]
        if bad.size:
            i = int(bad[0])
            raise AddaError(
                f"{path}: row {i + 2} has angles ({data[i, 0]}, {data[i, 1]}) deg but direction "
                f"{i} was ({th[i]:.4f}, {ph[i]:.4f}) deg: rows are not in the requested order"
            )
    return data[:, 2::2] + 1j * data[:, 3::2]


def _read_cross_sections(path: Path) -> dict[str, float]:
    out: dict[str, float] = {}
    if path.exists():
        for line in path.read_text().splitlines():
            name, _, value = line.partition("=")
            try:
                out[name.strip()] = float(value)
            except ValueError:
                continue
    return out


# -- running ADDA ----------------------------------------------------------------------------


@dataclass
class AddaResult:
    """One ADDA run: what was asked, what ADDA said, what it computed.

    Attributes
    ----------
    command : list of str
        The command line (file names relative to ``workdir``).
    returncode : int
    stdout, stderr : str
    seconds : float
        Wall time of the ADDA process.
    workdir : Path or None
        Where it ran (deleted afterwards unless the engine keeps files).
    ampl : ndarray or None
        ``[S1, S2, S3, S4]`` per requested direction.
    cross_sections : dict
        ``{"X": {"Cext": ...}, "Y": {...}}`` from ``CrossSec-X/Y``, um^2.
    log : str
        ADDA's log file.
    warnings : list of str
        ADDA's non-fatal ``WARNING`` messages.
    """

    command: list[str]
    returncode: int
    stdout: str
    stderr: str
    seconds: float
    workdir: Path | None = None
    ampl: NDArray[np.complex128] | None = None
    cross_sections: dict[str, dict[str, float]] = field(default_factory=dict)
    log: str = ""
    warnings: list[str] = field(default_factory=list)


def _messages(text: str, kind: str, continued: bool = True) -> list[str]:
    """ADDA's ``ERROR:`` or ``WARNING:`` messages in ``text``.

    ADDA wraps long messages; with ``continued`` the unprefixed lines that follow a message are
    joined to it (stderr carries nothing else).
    """
    out: list[str] = []
    for line in text.splitlines():
        stripped = line.strip()
        if not stripped:
            continue
        if re.match(r"(ERROR|WARNING|INFO):", stripped):
            # other kinds are kept as "" so that their continuation lines are not misattributed
            out.append(stripped if stripped.startswith(kind + ":") else "")
        elif continued and out and out[-1]:
            out[-1] += " " + stripped
    return [m for m in out if m]


def check_adda_output(command: list[str], returncode: int, stdout: str, stderr: str) -> list[str]:
    """Raise if an ADDA run failed; return its non-fatal warnings.

    A run fails if it exits non-zero, prints an ``ERROR`` (on stderr or stdout), or reports
    that the solver did not converge within ``-maxiter`` (ADDA only warns about that and exits
    0). The exception carries ADDA's message and the command line.

    Raises
    ------
    AddaError, AddaConvergenceError
    """
    cmd = shlex.join(command)
    errors = _messages(stderr, "ERROR") + _messages(stdout, "ERROR", continued=False)
    if returncode != 0 or errors:
        said = "; ".join(errors) if errors else (stderr.strip() or stdout.strip())[-2000:]
        status = f"exited with status {returncode}" if returncode != 0 else "reported an error"
        raise AddaError(f"ADDA {status}: {said or '(no message)'}\ncommand: {cmd}")
    found = _messages(stderr, "WARNING") + _messages(stdout, "WARNING", continued=False)
    for message in found:
        if _MAXITER_RE.search(message):
            raise AddaConvergenceError(
                f"ADDA did not converge: {message} (raise max_iterations or the tolerance)\n"
                f"command: {cmd}"
            )
    return found


def run_adda(binary: str | Path, args: list[str], workdir: Path,
             timeout_s: float | None = None) -> AddaResult:
    """Run ``binary args`` in ``workdir`` and check the outcome (:func:`check_adda_output`)."""
    command = [str(binary), *args]
    t0 = time.perf_counter()
    try:
        proc = subprocess.run(command, cwd=workdir, capture_output=True, text=True,
                              timeout=timeout_s, stdin=subprocess.DEVNULL)
    except subprocess.TimeoutExpired as exc:
        raise AddaError(f"ADDA did not finish within {timeout_s} s\ncommand: "
                        f"{shlex.join(command)}") from exc
    except OSError as exc:
        raise AddaError(f"could not start ADDA: {exc}\ncommand: {shlex.join(command)}") from exc
    seconds = time.perf_counter() - t0
    found = check_adda_output(command, proc.returncode, proc.stdout, proc.stderr)
    return AddaResult(command=command, returncode=proc.returncode, stdout=proc.stdout,
                      stderr=proc.stderr, seconds=seconds, workdir=workdir, warnings=found)


def adda_command(
    geometry: AddaGeometry,
    optics: Optics,
    orient_deg: tuple[float, float, float],
    shape_file: str,
    pairs_file: str,
    out_dir: str,
    tolerance: float,
    max_iterations: int,
    polarizability: str = "ldr",
) -> list[str]:
    """ADDA's arguments for one evaluation (see ``adda/README.md`` for why each is there)."""
    n_med = optics.n_medium
    m_args: list[str] = []
    for n in geometry.indices:
        m = complex(n) / n_med
        m_args += [repr(m.real), repr(m.imag)]
    return [
        "-shape", "read", shape_file,
        "-size", repr(geometry.size_um),
        "-m", *m_args,
        "-lambda", repr(optics.wavelength_medium_um),
        "-orient", *(repr(float(a)) for a in orient_deg),
        "-pol", polarizability,
        "-int", "poi",
        "-scat", "dr",
        "-iter", "qmr",
        "-eps", repr(-math.log10(tolerance)),
        "-maxiter", str(int(max_iterations)),
        "-scat_matr", "ampl",
        "-store_scat_grid",
        "-scat_grid_inp", pairs_file,
        "-dir", out_dir,
    ]


# -- the engine ------------------------------------------------------------------------------


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
        self._cache: OrderedDict[tuple, NDArray[np.complex128]] = OrderedDict()
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
            self._cache.move_to_end(key)
            return cached
        s, theta, phi = self._run(n)
        f = far_field_from_ampl(s, theta, phi, n, self.optics, self.rotation,
                                self.geometry.centre_offset_um, self.lab)
        self._cache[key] = f
        while len(self._cache) > 4:
            self._cache.popitem(last=False)
        return f

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


def far_field_from_ampl(
    s: ArrayLike, theta_deg: ArrayLike, phi_deg: ArrayLike, directions: ArrayLike,
    optics: Optics, rotation: ArrayLike, centre_offset_um: ArrayLike,
    lab: ArrayLike | None = None,
) -> NDArray[np.complex128]:
    """holofit's ``F(n)`` from ADDA's amplitude matrix (pure function of one run's numbers).

    Parameters
    ----------
    s : array_like, shape (M, 4)
        ADDA's ``[S1, S2, S3, S4]``.
    theta_deg, phi_deg : array_like, shape (M,)
        The ADDA angles that were requested (exact).
    directions : array_like, shape (M, 3)
        The same directions as holofit-lab unit vectors.
    optics : Optics
        For k and the instrument's polarisation (holofit lab).
    rotation : array_like, shape (3, 3)
        holofit's particle-to-lab rotation.
    centre_offset_um : array_like, shape (3,)
        Particle centre relative to ADDA's box centre, holofit particle frame, um.
    lab : array_like, shape (3, 3), optional
        holofit lab -> ADDA lab rotation of the run (default :func:`lab_map` of the optics'
        polarisation, as the engine runs ADDA; any other map superposes ADDA's X and Y
        solutions).

    Returns
    -------
    ndarray, shape (M, 3)
        Far-field vector in holofit's lab, phase origin at the particle centre.
    """
    m = lab_map(optics.polarization_rad) if lab is None else np.asarray(lab, dtype=float)
    e_adda = m @ optics.polarization
    f_adda = amplitude_vectors(s, theta_deg, phi_deg, e_adda)
    f_lab = f_adda @ m  # rows: M^T F
    s_lab = np.asarray(rotation, dtype=float) @ np.asarray(centre_offset_um, dtype=float)
    return f_lab * phase_origin_factor(directions, s_lab, optics.k)[:, None]


class AddaEngine(ScatteringTheory):
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
        self._geometries: OrderedDict[tuple, AddaGeometry] = OrderedDict()
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
        geom = self._geometries.get(key)
        if geom is None:
            geom = adda_geometry(self.lattice(model, optics))
            self._geometries[key] = geom
            while len(self._geometries) > 16:
                self._geometries.popitem(last=False)
        return geom

    def solve(self, model: ParticleModel, optics: Optics,
              orientation: Orientation | None = None) -> AddaWave:
        return AddaWave(self, model, optics, orientation or Orientation(),
                        self.geometry(model, optics))

    def run(self, geometry: AddaGeometry, optics: Optics, orient_deg: tuple[float, float, float],
            theta_deg: NDArray[np.float64], phi_deg: NDArray[np.float64]) -> AddaResult:
        """One ADDA run in a private temporary directory; reads and checks ``ampl_scatgrid``."""
        tmp = Path(tempfile.mkdtemp(prefix="holofit-adda-"))
        try:
            write_shape_file(tmp / "shape.dat", geometry)
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
                raise AddaError(f"{exc}\ncommand: {shlex.join(result.command)}") from None
            result.cross_sections = {pol: _read_cross_sections(out / f"CrossSec-{pol}")
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


ENGINES["adda"] = AddaEngine

