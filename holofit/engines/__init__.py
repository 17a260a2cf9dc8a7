"""Scattering engines by name, and the rule that picks one for a particle.

This package sits above :mod:`holofit.scattering` (the interface, the exact theories and what
the camera records) and :mod:`holofit.dda` (the discrete-dipole engines), because it creates
engines of both: :mod:`holofit.engines.registry` is the one list of engine names,
:mod:`holofit.engines.select` the ``auto`` rule every stage uses."""
