"""Building a lattice's T-matrix from DDA solves.

Construction (Mackowski 2002's "driving with regular waves", here with the lattice's
symmetries): the lattice is driven by incident fields whose regular-wave coefficient vectors
``c_s`` are the symmetry-adapted design of :func:`holofit.dda.tmatrix_symmetry.design_vectors`;
each field is synthesised on the dipoles from its plane-wave (Herglotz) density
(:func:`holofit.dda.tmatrix_incident.incident_on_lattice`), solved with the engine's Krylov
solver, and its far field on a Gauss-Legendre grid projected onto outgoing waves (``o_s``).
Then ``T = sum_g rho(g) (sum_s o_s c_s^H) rho(g)^H`` exactly, with ``~N/|G|`` solves for
``N = 2L(L+2)`` columns (``|G|`` = 16 for a rod on its lattice, 8 for a Janus particle).

Order
-----
``L`` is the smallest order whose truncation estimate is below ``truncation`` (default 3e-6):
the polarisability-weighted RMS over the dipoles of the plane wave's discarded tail,
``eps(L)^2 = sum_j |alpha_j| sum_{n>L} (2n+1) j_n(k r_j)^2 / sum_j |alpha_j|`` (the tail of
``sum_n (2n+1) j_n^2 = 1``, i.e. of the incident field each dipole feels; the scattered field's
discarded orders come from the same dipoles and fall off alike). The camera-field error
``max|dE|/max|E|`` of a truncated T-matrix lies well below the estimate; orientation
derivatives carry the truncated orders with a factor ~n, so the default is set by them (docs:
validation, "T-matrices").

Tolerance
---------
The solves run to a relative residual of 1e-6 by default; the T-matrix's camera-field error
from the solver then lies below the tolerance. Every build checks itself against one direct
DDA solve of a random plane wave and records that far-field error (truncation and solver
together) next to the estimate.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.special import spherical_jn
from threadpoolctl import threadpool_limits

from holofit.dda.dipoles import DipoleSystem
from holofit.dda.farfield import far_field, far_field_on_grid
from holofit.dda.lattice import Lattice
from holofit.dda.polarizability import INCIDENCE_INDEPENDENT
from holofit.dda.settings import DDASettings
from holofit.dda.solver import ConvergenceError, SolveResult
from holofit.dda.tmatrix_incident import incident_on_lattice, incident_quadrature
from holofit.dda.tmatrix_io import describe
from holofit.dda.tmatrix_symmetry import (
    SymmetryGroup,
    design_vectors,
    lattice_symmetries,
    symmetrize,
)
from holofit.dda.voxelize import voxelize
from holofit.optics import Optics
from holofit.particles import ParticleModel
from holofit.scattering.multipole import project_far_field
from holofit.scattering.tmatrix import TMatrix, z_rotation_order
from holofit.scattering.vsw import pack, plane_wave_coefficients

__all__ = [
    "DEFAULT_TRUNCATION",
    "BuildSettings",
    "BuildStats",
    "build_lattice_tmatrix",
    "build_tmatrix",
    "choose_order",
    "outgoing_coefficients",
    "truncation_estimate",
]

#: default target of the truncation estimate
DEFAULT_TRUNCATION = 3e-6
#: the build's solver tolerance never exceeds this (direct solves default to 1e-5)
MAX_BUILD_TOLERANCE = 1e-6
#: right-hand sides whose incident fields are synthesised together
CHUNK = 8
#: a build shares its solves by worker processes only when it has at least this much work
#: (dipoles x solves): starting a worker (imports, the interaction's FFT) costs one to three
#: seconds, a build of the paper's Janus particle (~35 000 dipoles, ~80 solves) a hundred
PARALLEL_MIN_WORK = 200_000
#: |b^T b| / |b|^2 below which QMR's Lanczos process is not trusted to start
BILINEAR_FLOOR = 1e-4


def truncation_estimate(k: float, radii: NDArray, weights: NDArray, order: int) -> float:
    """``eps(L)`` of the module docstring for dipoles at distances ``radii`` (um) from the
    centre with weights ``weights`` (|polarisability|)."""
    x = k * np.asarray(radii, dtype=float)
    n = np.arange(order + 1, order + 1 + int(np.ceil(x.max())) + 60)
    tail = np.sum((2 * n + 1)[None, :] * spherical_jn(n[None, :], x[:, None]) ** 2, axis=1)
    w = np.asarray(weights, dtype=float)
    return float(np.sqrt(np.sum(w * tail) / np.sum(w)))


def choose_order(k: float, radii: NDArray, weights: NDArray,
                 truncation: float = DEFAULT_TRUNCATION) -> tuple[int, float]:
    """Smallest ``L >= 1`` with ``truncation_estimate <= truncation``, and that estimate."""
    # unique radii (rounded) with summed weights: the estimate is a sum over radii
    r = np.round(np.asarray(radii, dtype=float), 12)
    uniq, inv = np.unique(r, return_inverse=True)
    w = np.bincount(inv, weights=np.asarray(weights, dtype=float))
    order = max(1, int(np.floor(k * uniq.max())) - 2)
    while True:
        est = truncation_estimate(k, uniq, w, order)
        if est <= truncation:
            return order, est
        order += 1


def _far_quadrature(order: int, k: float, radius: float) -> tuple[NDArray, NDArray, NDArray]:
    """Gauss-Legendre x uniform grid for projecting a far field onto orders <= L, exact for
    the degree ``L + K`` of the integrand (``K`` as in
    :func:`~holofit.dda.tmatrix_incident.incident_quadrature`); weights without ``2 pi/n_phi``."""
    mu, w, phi = incident_quadrature(order, k, radius)
    return mu, w * phi.size / (2.0 * np.pi), phi


def outgoing_coefficients(lattice: Lattice, P: NDArray[np.complex128], k: float, order: int,
                          grid: tuple[NDArray, NDArray, NDArray]) -> NDArray[np.complex128]:
    """Flat outgoing coefficients (particle frame) of the field radiated by dipoles ``P``."""
    mu, w, phi = grid
    a = 1j * far_field_on_grid(lattice, P, k, mu, phi)  # A = i F
    p, q = project_far_field(a, mu, w, phi, order)
    return pack(p, q)


@dataclass
class BuildStats:
    """What a build did: solves, iterations, time, symmetry, validation."""

    n_solves: int
    iterations: list[int]
    seconds: float
    symmetry_operations: int
    validation_far_field_error: float | None


@dataclass(frozen=True)
class BuildSettings:
    """How a lattice's T-matrix is built (:func:`build_lattice_tmatrix`).

    Attributes
    ----------
    tolerance : float
        Relative residual of every solve.
    order : int, optional
        Truncation order; by default from ``truncation``.
    truncation : float
        Target of the truncation estimate when ``order`` is not given.
    use_symmetry : bool
        Use the lattice's symmetries (one solve per ``|G|`` columns); False solves one
        right-hand side per column (for checks).
    max_iterations : int
        Solver iteration limit.
    validate : bool
        Compare against one direct solve of a random plane wave and record the far-field
        error.
    progress : callable, optional
        ``progress(done, total)`` after each solve.
    precision : {"double", "single"}
        Precision of the FFT convolution in the build's solves (the validation is in double).
    workers : int
        Processes the solves are shared by (1: in this process), for a build of at least
        :data:`PARALLEL_MIN_WORK`; the result does not depend on it.
    """

    tolerance: float = MAX_BUILD_TOLERANCE
    order: int | None = None
    truncation: float = DEFAULT_TRUNCATION
    use_symmetry: bool = True
    max_iterations: int = 2000
    validate: bool = True
    progress: Callable[[int, int], None] | None = None
    precision: str = "double"
    workers: int = 1


def build_lattice_tmatrix(
    lattice: Lattice, k: float, n_medium: float, polarizability: str,
    build: BuildSettings | None = None,
) -> tuple[TMatrix, BuildStats]:
    """T-matrix of a lattice (see the module docstring).

    Parameters
    ----------
    lattice : Lattice
        Dipoles, positions relative to the particle centre (the expansion centre).
    k : float
        Wavenumber in the medium, rad/um.
    n_medium : float
        Refractive index of the medium.
    polarizability : {"fcd", "ldr_avg", "cm"}
        An incidence-independent prescription.
    build : BuildSettings, optional
        How it is built (tolerance, order, symmetry, validation, precision, workers).
    """
    b = build or BuildSettings()
    tolerance, order, truncation, use_symmetry = b.tolerance, b.order, b.truncation, b.use_symmetry
    max_iterations, validate, progress, precision = (b.max_iterations, b.validate, b.progress,
                                                     b.precision)
    workers = b.workers
    if polarizability not in INCIDENCE_INDEPENDENT:
        raise ValueError(
            f"a T-matrix needs an incidence-independent polarizability {INCIDENCE_INDEPENDENT};"
            f" got {polarizability!r} (LDR's S term depends on the incident wave: use "
            "polarizability = 'fcd' or 'ldr_avg')"
        )
    t0 = time.perf_counter()
    dtype = np.complex64 if precision == "single" else np.complex128
    system = DipoleSystem(lattice, k, n_medium, polarizability, dtype)
    pos = lattice.positions
    radii = np.sqrt((pos**2).sum(axis=1))
    alpha = system.alpha(np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0]))
    weight = np.abs(alpha) if alpha.ndim == 1 else np.abs(alpha).mean(axis=1)
    if order is None:
        order, estimate = choose_order(k, radii, weight, truncation)
    else:
        estimate = truncation_estimate(k, radii, weight, order)
    eps = system.eps_rel
    ops = (lattice_symmetries(lattice, eps, per_axis=eps.ndim == 2) if use_symmetry
           else [np.eye(3, dtype=np.int64)])
    group = SymmetryGroup.from_operations(ops, order)
    design = design_vectors(group)
    n_solves = design.shape[1]
    workers = _build_workers(workers, n_solves, lattice.n_dipoles)
    out, iterations = _solve_design(system, design, alpha, order, float(radii.max()),
                                    tolerance, max_iterations, progress, workers, n_medium)
    dense = symmetrize(out @ design.conj().T, group)
    radius = float(radii.max() + lattice.d * np.sqrt(3) / 2)
    tm = TMatrix.from_dense(dense, order, k, radius, z_rotation_order(ops))
    error = None
    if validate:
        check = system if precision == "double" else DipoleSystem(lattice, k, n_medium,
                                                                  polarizability)
        error = _validate(tm, check, tolerance, max_iterations)
    stats = BuildStats(n_solves, iterations, time.perf_counter() - t0, len(ops), error)
    tm.provenance.update({
        "order": order, "truncation_estimate": estimate, "tolerance": tolerance,
        "n_solves": n_solves, "iterations_total": int(sum(iterations)),
        "symmetry_operations": len(ops), "validation_far_field_error": error,
        "n_dipoles": lattice.n_dipoles, "build_precision": precision,
        "build_seconds": stats.seconds, "build_workers": workers,
    })
    return tm, stats


def _build_workers(workers: int, n_solves: int, n_dipoles: int) -> int:
    """The processes a build uses: ``workers`` for a build of at least
    :data:`PARALLEL_MIN_WORK` of more than one chunk (at most one per chunk), else 1."""
    if workers > 1 and n_solves > CHUNK and n_solves * n_dipoles >= PARALLEL_MIN_WORK:
        return min(int(workers), -(-n_solves // CHUNK))
    return 1


def _solve_design(
    system: DipoleSystem, design: NDArray, alpha: NDArray, order: int, radius_um: float,
    tolerance: float, max_iterations: int, progress: Callable[[int, int], None] | None,
    workers: int = 1, n_medium: float = 1.0,
) -> tuple[NDArray[np.complex128], list[int]]:
    """Outgoing coefficients of every design vector (one DDA solve each, incident fields in
    chunks of :data:`CHUNK`) and the solves' iteration counts; with ``workers`` > 1 the chunks
    are shared by that many processes (:func:`_solve_design_parallel`)."""
    n_solves = design.shape[1]
    if workers > 1:
        return _solve_design_parallel(system, design, order, radius_um, tolerance,
                                      max_iterations, progress, workers, n_medium)
    out = np.empty_like(design)
    iterations: list[int] = []
    for start in range(0, n_solves, CHUNK):
        got, its = _solve_chunk(system, design[:, start : start + CHUNK], alpha, order,
                                radius_um, tolerance, max_iterations)
        out[:, start : start + got.shape[1]] = got
        for j, n in enumerate(its):
            iterations.append(n)
            if progress is not None:
                progress(start + j + 1, n_solves)
    return out, iterations


def _solve_chunk(system: DipoleSystem, cols: NDArray, alpha: NDArray, order: int,
                 radius_um: float, tolerance: float, max_iterations: int
                 ) -> tuple[NDArray[np.complex128], list[int]]:
    """Outgoing coefficients of a few design vectors (their incident fields synthesised
    together) and the iterations of their solves."""
    lattice, k = system.lattice, system.k
    grid = _far_quadrature(order, k, radius_um)
    fields = incident_on_lattice(lattice, cols, k, order)
    out = np.empty_like(cols)
    iterations = []
    for j in range(cols.shape[1]):
        P, res = _solve(system, fields[j], alpha, tolerance, max_iterations)
        iterations.append(res.iterations)
        out[:, j] = outgoing_coefficients(lattice, P, k, order, grid)
    return out, iterations


#: per build worker process: the dipole system of the build it serves
_WORKER_SYSTEM: list[DipoleSystem] = []


def _init_build_worker(lattice: Lattice, k: float, n_medium: float, polarizability: str,
                       dtype: str) -> None:
    """A build worker's start: its dipole system (the interaction's FFT: about one solve)."""
    _WORKER_SYSTEM[:] = [DipoleSystem(lattice, k, n_medium, polarizability,
                                      np.dtype(dtype).type)]


def _chunk_task(cols: NDArray, order: int, radius_um: float, tolerance: float,
                max_iterations: int) -> tuple[NDArray[np.complex128], list[int]]:
    """:func:`_solve_chunk` in a build worker."""
    system = _WORKER_SYSTEM[0]
    alpha = system.alpha(np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0]))
    with threadpool_limits(limits=1, user_api="blas"):
        return _solve_chunk(system, cols, alpha, order, radius_um, tolerance, max_iterations)


def _solve_design_parallel(
    system: DipoleSystem, design: NDArray, order: int, radius_um: float, tolerance: float,
    max_iterations: int, progress: Callable[[int, int], None] | None, workers: int,
    n_medium: float,
) -> tuple[NDArray[np.complex128], list[int]]:
    """:func:`_solve_design` on ``workers`` freshly spawned processes, one chunk of
    :data:`CHUNK` design vectors a task (the solves are independent: the same T-matrix, the
    iterations of each solve unchanged). Each worker makes the dipole system once (its
    interaction's FFT: about a solve's time)."""
    import concurrent.futures as cf
    import multiprocessing

    n_solves = design.shape[1]
    starts = list(range(0, n_solves, CHUNK))
    out = np.empty_like(design)
    its: dict[int, list[int]] = {}
    done = 0
    with cf.ProcessPoolExecutor(
            max_workers=min(workers, len(starts)),
            mp_context=multiprocessing.get_context("spawn"), initializer=_init_build_worker,
            initargs=(system.lattice, system.k, n_medium, system.pol,
                      system.dtype.name)) as pool:
        futures = {pool.submit(_chunk_task, design[:, s : s + CHUNK], order, radius_um,
                               tolerance, max_iterations): s for s in starts}
        for fut in cf.as_completed(futures):
            s = futures[fut]
            got, it = fut.result()
            out[:, s : s + got.shape[1]] = got
            its[s] = it
            done += len(it)
            if progress is not None:
                progress(done, n_solves)
    return out, [n for s in starts for n in its[s]]


def _solve(system: DipoleSystem, e_inc: NDArray, alpha: NDArray, tolerance: float,
           max_iterations: int) -> tuple[NDArray, SolveResult]:
    """QMR (one product per iteration), BiCGStab where complex-symmetric Lanczos would break
    down (``b^T b ~ 0``) or did not converge."""
    b = (np.sqrt(alpha) if alpha.ndim == 2 else np.sqrt(alpha)[:, None]) * e_inc
    safe = abs(np.sum(b * b)) > BILINEAR_FLOOR * float(np.sum(np.abs(b) ** 2))
    if safe:
        try:
            return system.solve_field(e_inc, tol=tolerance, maxiter=max_iterations)
        except ConvergenceError:
            pass
    return system.solve_field(e_inc, tol=tolerance, maxiter=max_iterations, method="bicgstab")


def _validate(tm: TMatrix, system: DipoleSystem, tolerance: float, max_iterations: int) -> float:
    """Max far-field error (relative to the max) of ``tm`` against one direct solve."""
    rng = np.random.default_rng(7)
    a = rng.normal(size=3)
    a /= np.linalg.norm(a)
    e = np.cross(a, rng.normal(size=3))
    e /= np.linalg.norm(e)
    sol = system.solve(a, e, tol=min(tolerance, 1e-8), maxiter=max_iterations)
    dirs = rng.normal(size=(256, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    direct = far_field(system.lattice, sol.P, system.k, dirs)
    o = tm.scatter(plane_wave_coefficients(a, e, tm.order))
    from_t = -1j * tm.expansion(o).far_amplitude(dirs)  # F = -i A
    return float(np.abs(from_t - direct).max() / np.abs(direct).max())


def build_tmatrix(
    model: ParticleModel, optics: Optics, settings: DDASettings | None = None,
    order: int | None = None, truncation: float = DEFAULT_TRUNCATION,
    tolerance: float | None = None, use_symmetry: bool = True, validate: bool = True,
    progress: Callable[[int, int], None] | None = None, precision: str = "single",
    workers: int = 1,
) -> TMatrix:
    """The T-matrix of ``model`` on the lattice the built-in engine uses with ``settings``.

    ``settings.polarizability`` must be incidence-independent (``"fcd"``, the default,
    ``"ldr_avg"`` or ``"cm"``);
    the solver tolerance is ``min(settings.tolerance, 1e-6)`` unless ``tolerance`` is given.
    The solves use the single-precision FFT convolution by default (``precision``): the
    iterations and the T-matrix's error are unchanged at these tolerances (docs: validation,
    "T-matrices"); the build's validation solve stays in double.
    The provenance (:func:`holofit.dda.tmatrix_io.describe` plus the build's numbers) is
    stored in the result.

    The build runs its linear algebra on one BLAS thread: its many small solves and products
    gain nothing from a thread pool, which spends several times the CPU on them (docs:
    validation, "T-matrices"). ``workers`` > 1
    shares its solves by that many processes instead (:func:`build_lattice_tmatrix`).
    """
    with threadpool_limits(limits=1, user_api="blas"):
        return _build_tmatrix(model, optics, settings, order, truncation, tolerance,
                              use_symmetry, validate, progress, precision, workers)


def _build_tmatrix(
    model: ParticleModel, optics: Optics, settings: DDASettings | None, order: int | None,
    truncation: float, tolerance: float | None, use_symmetry: bool, validate: bool,
    progress: Callable[[int, int], None] | None, precision: str, workers: int = 1,
) -> TMatrix:
    settings = settings or DDASettings()
    if settings.polarizability not in INCIDENCE_INDEPENDENT:
        raise ValueError(
            f"dda polarizability {settings.polarizability!r} depends on the incident wave, so "
            f"the lattice has no T-matrix; set polarizability to one of {INCIDENCE_INDEPENDENT}"
        )
    d = settings.dipole_size_for(model, optics)
    lattice = voxelize(model, d, settings.filling)
    tol = tolerance if tolerance is not None else min(settings.tolerance, MAX_BUILD_TOLERANCE)
    tm, _ = build_lattice_tmatrix(
        lattice, optics.k, optics.n_medium, settings.polarizability,
        BuildSettings(tolerance=tol, order=order, truncation=truncation,
                      use_symmetry=use_symmetry, max_iterations=settings.max_iterations,
                      validate=validate, progress=progress, precision=precision,
                      workers=workers),
    )
    tm.provenance = {**describe(model, d, optics, settings, lattice), **tm.provenance}
    return tm
