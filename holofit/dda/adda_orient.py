"""From an ADDA run to holofit: the orientation of a shape file given ADDA's ``-orient``.

A user with an ADDA shape file and ADDA's ``-orient alpha beta gamma`` (zyz, degrees) gets the
same physical configuration in holofit by reading the file as a
:class:`~holofit.particles.VoxelShape` (its frame is then holofit's particle frame, unchanged) and
giving the orientation returned here.

ADDA rotates the particle by ``R_adda = Rz(alpha) Ry(beta) Rz(gamma)`` into a lab where the
light travels along +z, polarised along x ("X") or y ("Y"). holofit's lab has the light along
-z, polarised at ``beta_pol`` from x; the rotation ``M = Rx(pi) Rz(-beta_pol)`` maps holofit's
lab onto ADDA's with the instrument's polarisation on ADDA's x. A particle-frame point at
``r`` is at ``R_adda r`` in ADDA's lab and at ``R r`` in holofit's, so ``R_adda = M R`` and

    R = Rz(beta_pol) Rx(pi) Rz(alpha) Ry(beta) Rz(gamma).

Taking holofit's ``(psi, theta, phi) = (alpha, beta, gamma)`` instead (the same zyz form,
but the wrong lab) differs by the ``Rx(pi)`` in front: harmless only for particles symmetric
under a rotation by pi about x (a sphere, a rod), but it puts a Janus cap on the wrong side.

Phase origin: ADDA refers phases to the centre of the dipole box; a ``VoxelShape`` with
``centre_um = (0, 0, 0)`` does too.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from holofit.conventions import euler_zyz, euler_zyz_from_matrix
from holofit.dda.adda.frames import lab_map
from holofit.scattering.theory import Orientation

__all__ = ["orientation_from_adda"]


def orientation_from_adda(orient_deg: Sequence[float] = (0.0, 0.0, 0.0),
                          polarization_rad: float = 0.0) -> Orientation:
    """holofit orientation of an ADDA shape file's particle for ADDA's ``-orient`` angles.

    Parameters
    ----------
    orient_deg : sequence of 3 floats
        ADDA's ``-orient alpha beta gamma``, degrees.
    polarization_rad : float
        The instrument's polarisation angle in holofit's lab; ADDA's "X" solution is the one
        that corresponds to it.

    Returns
    -------
    Orientation
        ``(psi, theta, phi)`` with ``Rz(psi) Ry(theta) Rz(phi) = Rz(beta_pol) Rx(pi) R_adda``.
    """
    if len(orient_deg) != 3:
        raise ValueError(f"ADDA -orient takes three angles (alpha beta gamma), got {orient_deg}")
    r_adda = euler_zyz(*np.radians(np.asarray(orient_deg, dtype=float)))
    rot = lab_map(polarization_rad).T @ r_adda  # ADDA's lab back to holofit's
    psi, theta, phi = (float(v) for v in euler_zyz_from_matrix(rot))
    return Orientation(psi, theta, phi)
