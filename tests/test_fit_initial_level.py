"""The initial pass's rows clearly worse than its best ones (holofit.quality.flag_off_level):
flagged
on simulated reduced chi^2 with known labels, never flagging right-minimum rows, and kept out of
the static parameters and the final pass's bar."""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest

from holofit.fit.chunk_task import FIXED_STATICS_FLOOR, REFIT_MIN_ROWS, bar_from_initial
from holofit.fit.initial_pass import flag_initial
from holofit.fit.static import static_average
from holofit.io.tables import read_table, sidecar_path, write_table
from holofit.particles import JanusSphere
from holofit.quality import chi2_bar, flag_off_level, initial_level, small_sample_bar

N_PIXELS = 19600
JANUS = JanusSphere(0.443, 0.047, 1.581, 2.74)


def _table(chi2, caps=None, status="ok"):
    n = len(chi2)
    caps = np.full(n, 0.047) if caps is None else np.asarray(caps)
    return pd.DataFrame(
        {
            "particle": 0,
            "frame": np.arange(n),
            "status": status,
            "message": "",
            "chi2_red": chi2,
            "n_pixels": N_PIXELS,
            "radius_um": 0.443,
            "cap_thickness_um": caps,
            "n_core": 1.581,
            "n_cap": 2.74,
        }
    )


def _right(rng, n, level=1.02, excess=0.01):
    """Right-minimum rows: the chi^2 distribution's scatter plus an excess (relative sd)."""
    return level * (1 + rng.normal(0.0, math.sqrt(2 / N_PIXELS + excess**2), n))


def test_a_chunk_in_a_wrong_minimum_is_flagged_and_leaves_the_statics():
    """The Janus replicate's initial pass (measured): one chunk's 5 frames near the truth,
    the other's 6 from a start 26 deg off, at chi^2_red 1.06-1.27 with its caps far off."""
    chi = [1.264, 1.273, 1.121, 1.059, 1.162, 1.132, 1.034, 1.029, 1.024, 1.005, 1.020]
    caps = [0.041, 0.034, 0.032, 0.024, 0.022, 0.022, 0.043, 0.053, 0.043, 0.039, 0.042]
    table = _table(chi, caps)
    before = static_average(table, JANUS)["values"]["cap_thickness_um"]
    assert flag_off_level(table, 4.0) == 5
    flagged = table["status"] == "poor_fit"
    assert set(table.loc[flagged, "frame"]) == {0, 1, 2, 4, 5}
    assert table.loc[flagged, "message"].str.contains("best quarter").all()
    after = static_average(table, JANUS)["values"]["cap_thickness_um"]
    assert abs(after - 0.047) < abs(before - 0.047)  # median closer to the truth's cap
    assert flag_off_level(table, 4.0) == 0  # applying it twice changes nothing more


def test_right_minimum_rows_are_not_flagged():
    """Short (8 rows) and long (100 rows) passes of right-minimum frames, 1 % excess scatter:
    next to no row above the level (a false flag only drops a row from the median)."""
    rng = np.random.default_rng(3)
    false = total = 0
    for n in [8] * 300 + [100] * 30:
        table = _table(_right(rng, n))
        false += flag_off_level(table, 4.0)
        total += n
    assert false / total < 2e-3


def test_an_off_row_among_right_ones_is_caught():
    rng = np.random.default_rng(4)
    caught = 0
    for _ in range(200):
        chi = _right(rng, 8)
        chi[3] = 1.02 * 1.12  # 12 % above the right level: a wrong branch (measured: 6-25 %)
        table = _table(chi)
        flag_off_level(table, 4.0)
        caught += table.loc[3, "status"] == "poor_fit"
    assert caught == 200


def test_too_few_rows_no_level():
    assert math.isnan(initial_level(_table([1.0, 1.3, 1.01]), 4.0))
    assert flag_off_level(_table([1.0, 1.3, 1.01]), 4.0) == 0


def test_the_table_is_rewritten_with_its_sidecar_and_the_bar_ignores_flagged_rows(tmp_path):
    """Half the rows off (the replicate's case): the final pass's bar is the right rows' own
    bar, not the contaminated one of all rows."""
    rng = np.random.default_rng(5)
    chi = _right(rng, 12)
    off = [0, 1, 2, 4, 5]
    chi[off] = [1.26, 1.27, 1.12, 1.16, 1.13]
    path = write_table(tmp_path / "initial.csv", _table(chi), {"kind": "fit table"})
    bar_all, _ = bar_from_initial(path, 4.0)
    table = read_table(path)
    level = flag_initial(table, 4.0)
    write_table(path, table, {"kind": "fit table", "initial_level": level})
    table = read_table(path)
    assert list(table.index[table["status"] == "poor_fit"]) == off
    meta = json.loads(sidecar_path(path).read_text())
    assert meta["kind"] == "fit table" and meta["initial_level"]["flagged"] == len(off)
    bar, note = bar_from_initial(path, 4.0)
    right = _table(np.delete(chi, off))
    assert bar == pytest.approx(small_sample_bar(right, 4.0), rel=1e-8)  # (CSV round trip)
    assert bar < 1.1 < bar_all
    assert "7 ok frame(s)" in note
    assert flag_initial(read_table(path), 4.0) is None


def test_the_bar_is_taken_from_the_initial_frames_as_the_final_pass_fits_them(tmp_path):
    """With ``refit``, the bar is that of the refitted rows (the statics fixed raise every
    frame's chi^2 above its own minimum's), not of the initial rows; from fewer than
    ``REFIT_MIN_ROWS`` of them, with the spread at least the noise model's with the fixed
    statics' excess."""
    rng = np.random.default_rng(6)
    chi = _right(rng, 10, level=1.01)
    path = write_table(tmp_path / "initial.csv", _table(chi), {"kind": "fit table"})
    own, _ = bar_from_initial(path, 4.0)
    fixed = _right(rng, 10, level=1.06)

    def refit(rows):
        assert len(rows) == 10 and (rows["status"] == "ok").all()
        return _table(fixed)

    bar, note = bar_from_initial(path, 4.0, refit)
    expected = small_sample_bar(_table(fixed), 4.0, REFIT_MIN_ROWS, FIXED_STATICS_FLOOR)
    assert bar == pytest.approx(expected) and bar > own
    assert bar > chi2_bar(_table(fixed), 4.0)  # wider than 10 consecutive frames' own spread
    assert "refitted with the final statics" in note
