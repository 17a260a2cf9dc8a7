"""ADDA (the Amsterdam DDA code) as an alternative scattering engine, driven as the user's own
binary behind holofit's :class:`~holofit.scattering.theory.ScatteringEngine` interface.

One module per job:

- :mod:`~holofit.dda.adda.binary`: finding the binary, its version;
- :mod:`~holofit.dda.adda.frames`: frame algebra between holofit and ADDA (labs, ``-orient``,
  amplitude-matrix basis, phase origin);
- :mod:`~holofit.dda.adda.files`: shape, pairs, ``ampl_scatgrid`` and cross-section files;
- :mod:`~holofit.dda.adda.run`: the command line and the subprocess;
- :mod:`~holofit.dda.adda.engine`: :class:`AddaEngine` and :class:`AddaWave`;
- :mod:`~holofit.dda.adda.errors`: its errors and warnings.
"""

from holofit.dda.adda.binary import (
    ADDA_ENV_VAR,
    TESTED_VERSIONS,
    AddaVersion,
    adda_version,
    find_adda,
    parse_version,
)
from holofit.dda.adda.engine import AddaEngine, AddaWave
from holofit.dda.adda.errors import (
    AddaConvergenceError,
    AddaError,
    AddaFarFieldWarning,
    AddaNotFoundError,
    AddaWarning,
)
from holofit.dda.adda.files import (
    AddaGeometry,
    adda_geometry,
    read_ampl_scatgrid,
    read_cross_sections,
    write_geometry,
    write_pairs_file,
)
from holofit.dda.adda.frames import (
    T_LAB,
    adda_amplitude_matrix,
    adda_orientation_deg,
    amplitude_vectors,
    far_field_from_ampl,
    lab_map,
    lab_to_adda_angles,
    orientation_from_adda,
    phase_origin_factor,
)
from holofit.dda.adda.run import AddaResult, adda_command, check_adda_output, run_adda

__all__ = [
    "ADDA_ENV_VAR",
    "TESTED_VERSIONS",
    "T_LAB",
    "AddaConvergenceError",
    "AddaEngine",
    "AddaError",
    "AddaFarFieldWarning",
    "AddaGeometry",
    "AddaNotFoundError",
    "AddaResult",
    "AddaVersion",
    "AddaWarning",
    "AddaWave",
    "adda_amplitude_matrix",
    "adda_command",
    "adda_geometry",
    "adda_orientation_deg",
    "adda_version",
    "amplitude_vectors",
    "check_adda_output",
    "far_field_from_ampl",
    "find_adda",
    "lab_map",
    "lab_to_adda_angles",
    "orientation_from_adda",
    "parse_version",
    "phase_origin_factor",
    "read_ampl_scatgrid",
    "read_cross_sections",
    "run_adda",
    "write_geometry",
    "write_pairs_file",
]
