"""The initial pass's frames that fit clearly worse than its best ones: ``poor_fit``, so that
they fix neither the static parameters nor the final pass's chi^2 bar.

The initial pass fits every parameter of a few frames, the static ones included, and the
final pass takes the median of their ``ok`` rows (:mod:`holofit.fit.static`) and its chi^2
bar from them (:func:`holofit.fit.tracked.bar_from_initial`). Along a track a chunk's frames
follow its first, library-started fit: a first fit in a wrong minimum carries its whole chunk
with it, and with the static parameters free the fits settle far along their valleys
(measured on a 3000-frame Janus replicate: a chunk started 26 deg off the truth's tilt, from a
prefit height 0.47 um off, reached chi^2_red 1.06-1.27 with caps of 22-41 nm and cap indices
of 2.8-4.2, while the other chunk's frames reached 1.005-1.034 near the truth). Left ``ok``,
such rows pull the median and raise the bar. There is no bar within the initial pass, and
the rows' own median is not a safe reference when half of them may be off, so the reference
is the pass's best quarter:

    level = q25 * (1 + sigmas * spread),
    spread = max(sqrt(2 / nu + floor^2), (q25 - q05) / (0.971 q25)),

with ``q25``, ``q05`` the 25 % and 5 % quantiles of the converged rows' reduced chi^2, ``nu``
their median pixel count, ``floor`` :data:`holofit.fit.continuity.EXCESS_FLOOR` (the excess a
right-minimum frame shows at least: the noise model's spread, as
:func:`holofit.fit.continuity.small_sample_bar` takes it) and ``0.971`` the distance, in
standard deviations, from a normal sample's 5 % to its 25 % quantile (the measured spread of
the best rows, for a long pass). ``ok`` rows above the level become ``poor_fit`` with a
message that says so. Rows are only ever flagged, and the quantiles are taken over ``ok`` and
``poor_fit`` rows alike, which flagging does not change: a second application changes nothing.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd

from holofit.fit.continuity import EXCESS_FLOOR
from holofit.io.tables import read_table, sidecar_path, write_table
from holofit.status import OK, POOR_FIT

__all__ = ["flag_initial_table", "flag_off_level", "initial_level"]

#: a normal sample's 25 % quantile lies this many standard deviations above its 5 % one
_Q05_TO_Q25_SIGMAS = 0.971
#: fewer converged rows than this: no level (a quarter of them is not a reference)
MIN_ROWS = 4


def initial_level(table: pd.DataFrame, sigmas: float,
                  excess_floor: float = EXCESS_FLOOR) -> float:
    """The reduced chi^2 above which an initial-pass row fits clearly worse than the pass's
    best quarter of frames (see the module docstring).

    Parameters
    ----------
    table : DataFrame
        The initial pass's table (``status``, ``chi2_red``, ``n_pixels``).
    sigmas : float
        How many spreads above the best quarter (the final pass's bar uses the same number).
    excess_floor : float
        Least relative excess scatter of a right-minimum frame.

    Returns
    -------
    float
        The level; NaN with fewer than :data:`MIN_ROWS` converged rows or no pixel count.
    """
    conv = table["status"].isin((OK, POOR_FIT)).to_numpy()
    chi = table["chi2_red"].to_numpy(dtype=float)
    keep = conv & np.isfinite(chi)
    if int(keep.sum()) < MIN_ROWS or "n_pixels" not in table:
        return math.nan
    nu = table["n_pixels"].to_numpy(dtype=float)[keep]
    nu = nu[np.isfinite(nu) & (nu > 0)]
    if nu.size == 0:
        return math.nan
    q05, q25 = (float(q) for q in np.percentile(chi[keep], [5.0, 25.0]))
    noise = math.sqrt(2.0 / float(np.median(nu)) + excess_floor**2)
    measured = (q25 - q05) / (_Q05_TO_Q25_SIGMAS * q25) if q25 > 0 else 0.0
    return q25 * (1.0 + sigmas * max(noise, measured))


def flag_off_level(table: pd.DataFrame, sigmas: float) -> int:
    """Mark the ``ok`` rows above :func:`initial_level` ``poor_fit`` (in place).

    Returns
    -------
    int
        Rows newly flagged.
    """
    level = initial_level(table, sigmas)
    if not math.isfinite(level):
        return 0
    chi = table["chi2_red"].to_numpy(dtype=float)
    off = (table["status"] == OK).to_numpy() & (chi > level)
    if not off.any():
        return 0
    table.loc[off, "status"] = POOR_FIT
    note = (f"chi2_red above {level:.4g}, the initial pass's best quarter of frames + "
            f"{sigmas:g} spreads: a wrong minimum or a start far off; not used for the static "
            "parameters")
    if "message" not in table:
        table["message"] = ""
    table["message"] = table["message"].astype(object)
    table.loc[off, "message"] = [f"{m}; {note}" if isinstance(m, str) and m else note
                                 for m in table.loc[off, "message"]]
    return int(off.sum())


def flag_initial_table(path: Path, sigmas: float) -> int:
    """:func:`flag_off_level` on the initial pass's table at ``path``, written back
    (atomically, its sidecar recording the level) when a row changed; the rows newly flagged."""
    table = read_table(path)
    flagged = flag_off_level(table, sigmas)
    if flagged:
        meta = json.loads(sidecar_path(path).read_text())
        meta["initial_level"] = {"chi2_red": initial_level(table, sigmas), "sigmas": sigmas,
                                 "flagged": flagged,
                                 "rule": "ok rows above the best quarter's level become "
                                         "poor_fit (holofit.fit.initial_level)"}
        write_table(path, table, meta)
    return flagged
