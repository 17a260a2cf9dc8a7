"""Exact T-matrices of bodies of revolution: spherocylinders, spheroids, cylinders, Janus and
layered spheres.

A body of revolution about particle z couples the azimuthal order ``m`` only to itself, so its
T-matrix is one small block per ``m``, in the basis, normalisation and storage of
:class:`holofit.scattering.tmatrix.TMatrix` (modulus ``2L + 1``): every orientation is then a
Wigner rotation, as for the DDA-built T-matrix. Modules, one job each:

* :mod:`~holofit.scattering.axisym.profiles` - the bodies as ``eps(r, theta)`` and surfaces;
* :mod:`~holofit.scattering.axisym.angular` - exact split angular integrals;
* :mod:`~holofit.scattering.axisym.bessel` - Riccati-Bessel functions for the radial march;
* :mod:`~holofit.scattering.axisym.iitm` - invariant imbedding (inhomogeneous bodies);
* :mod:`~holofit.scattering.axisym.ebcm` - extended boundary condition method (homogeneous);
* :mod:`~holofit.scattering.axisym.blocks` - per-``m`` blocks to a :class:`TMatrix`;
* :mod:`~holofit.scattering.axisym.order` - the truncation order's start and estimate;
* :mod:`~holofit.scattering.axisym.build` - method, order, provenance:
  :func:`build_exact_tmatrix`, :func:`supports`;
* :mod:`~holofit.scattering.axisym.engine` - the ``exact`` engine, :class:`AxisymmetricTMatrix`.
"""

from __future__ import annotations

from holofit.scattering.axisym.build import build_exact_tmatrix, supports
from holofit.scattering.axisym.engine import AxisymmetricTMatrix
from holofit.scattering.axisym.profiles import TaperedJanusSphere

__all__ = ["AxisymmetricTMatrix", "TaperedJanusSphere", "build_exact_tmatrix", "supports"]
