"""The discrete dipole approximation: holofit's own engine (:mod:`holofit.dda.engine`) and the
adapter that drives a user's ADDA binary (:mod:`holofit.dda.adda`), which share the particle
discretisation (:mod:`holofit.dda.voxelize`, :mod:`holofit.dda.lattice`) and settings
(:mod:`holofit.dda.settings`)."""
