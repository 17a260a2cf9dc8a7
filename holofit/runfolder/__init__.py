"""Run folders driven by make: one folder per movie, one make target per stage.

``holofit init RUN --movie raw.tif --background bg.tif -i INSTRUMENT -p PARTICLE`` writes
``RUN/Makefile``, ``RUN/README.md`` and copies of the two configs; ``make -C RUN`` then runs
crop -> prefit -> library -> fit (initial, final) -> analyze, reruns only what a changed input
invalidates, and resumes an interrupted stage from its journal
(:mod:`holofit.runfolder.makefile` says how). Modules: :mod:`~holofit.runfolder.spec` (what
the Makefile needs, checked), :mod:`~holofit.runfolder.makefile` and
:mod:`~holofit.runfolder.readme` (the texts), :mod:`~holofit.runfolder.create` (writing the
folder).
"""

from holofit.runfolder.create import (
    RunFolder,
    RunInputs,
    default_holofit_command,
    init_run,
    write_batch_makefile,
)
from holofit.runfolder.errors import RunFolderError
from holofit.runfolder.makefile import targets
from holofit.runfolder.spec import STAGES, RunFolderConfig

__all__ = [
    "STAGES",
    "RunFolder",
    "RunFolderConfig",
    "RunFolderError",
    "RunInputs",
    "default_holofit_command",
    "init_run",
    "targets",
    "write_batch_makefile",
]
