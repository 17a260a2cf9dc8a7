"""Scattering theories: the interface every engine implements (:mod:`holofit.scattering.theory`),
the engine-independent machinery (multipole expansions, vector spherical waves, Wigner
rotations, T-matrices and the waves they serve), the exact theories (Lorenz-Mie for spheres and
coated spheres, sphere clusters) and what the camera records
(:mod:`holofit.scattering.recorded_field`, through the objective lens of
:mod:`holofit.scattering.lens` when the optics have a numerical aperture)."""
