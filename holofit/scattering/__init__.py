"""Scattering theories: the interface every engine implements (:mod:`holofit.scattering.theory`),
exact Lorenz-Mie for spheres and coated spheres, the engine registry and choice, and what the
camera records (:mod:`holofit.scattering.recorded_field`, through the objective lens of
:mod:`holofit.scattering.lens` when the optics have a numerical aperture)."""
