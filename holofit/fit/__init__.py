"""The DDA fit of every frame of every track (the paper's steps 5-6).

By job:

- one frame: :mod:`~holofit.fit.problem` (:class:`FrameProblem`), :mod:`~holofit.fit.frame`
  (from the library's starts), :mod:`~holofit.fit.warm` (from a known state; one
  evaluation), :mod:`~holofit.fit.seeded` (the pose from a T-matrix, then every parameter),
  :mod:`~holofit.fit.settings`;
- following a track from frame to frame: :mod:`~holofit.fit.follow`,
  :mod:`~holofit.fit.follower`;
- the rescue steps of a wrong minimum: :mod:`~holofit.fit.rescue`,
  :mod:`~holofit.fit.continuity` and :mod:`~holofit.fit.sweeps`;
- how good a fit is: :mod:`holofit.quality`;
- chunks of a track and their stitching: :mod:`~holofit.fit.chunks`,
  :mod:`~holofit.fit.chunk_task`;
- neighbours' overlapping holograms: :mod:`~holofit.fit.overlaps`;
- the passes and the stage: :mod:`~holofit.fit.passes`, :mod:`~holofit.fit.static`,
  :mod:`~holofit.fit.tmatrix_policy`, :mod:`~holofit.fit.task`, :mod:`~holofit.fit.stage`.
"""
