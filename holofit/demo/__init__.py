"""The demos of ``holofit demo``: a rod movie (:mod:`holofit.demo.rod`) and a sphere movie
(:mod:`holofit.demo.sphere`), simulated, run through the pipeline and compared with the truth."""
