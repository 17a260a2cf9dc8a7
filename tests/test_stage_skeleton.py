"""The stage skeleton: one frame check, one skip policy, one fingerprint for every stage."""

from __future__ import annotations

import hashlib
import json
import math

import numpy as np
import pandas as pd
import pytest

from holofit.batch import Precomputed
from holofit.batch.stage import FrameLoader, FrameStart, check_frames, crop_skip, fingerprint
from holofit.prefit.sphere import SPHERE_COLUMNS, START_COLUMNS
from holofit.tables.cropset import CropSetError
from holofit.tables.prefit import SPHERE_FIT_COLUMNS, SPHERE_START_COLUMNS


def test_fingerprint_is_the_sha256_of_canonical_json():
    doc = {"b": [1, 2.5], "a": {"z": None, "y": "text"}}
    want = hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()[:16]
    assert fingerprint(doc) == want
    assert fingerprint({"a": {"y": "text", "z": None}, "b": [1, 2.5]}) == want  # key order
    assert fingerprint({**doc, "b": [1, 2.6]}) != want


def test_prefit_table_columns_are_the_sphere_fit_s():
    assert SPHERE_FIT_COLUMNS == SPHERE_COLUMNS
    assert SPHERE_START_COLUMNS == START_COLUMNS


class _Crops:
    """A stand-in crop folder: frames 0-3, frame 1 without a particle."""

    def __init__(self):
        self.frames = [0, 1, 2, 3]
        self.keys = [(0, f) for f in self.frames]
        self.table_path = "crops.csv"

    def row(self, frame):
        if frame == 1:
            return {"frame": 1, "status": "no_particle", "message": "nothing found",
                    "x_um": math.nan, "y_um": math.nan, "corner_row": None, "corner_col": None}
        return {"frame": frame, "status": "ok", "message": "", "x_um": 5.0, "y_um": 6.0,
                "corner_row": 10 + frame, "corner_col": 20}

    def crop(self, frame):
        return np.full((4, 4), float(frame), dtype=np.float32)


def test_unknown_frames_refused_with_the_crop_table_named():
    assert check_frames(_Crops(), None) == [(0, 0), (0, 1), (0, 2), (0, 3)]
    assert check_frames(_Crops(), [3, 0]) == [(0, 3), (0, 0)]
    with pytest.raises(CropSetError, match=r"crops.csv: no frame\(s\) \[7, 9\]"):
        check_frames(_Crops(), [0, 9, 7])


def test_skip_policy_in_order_crop_prefit_library():
    prefit = pd.DataFrame({"frame": [0, 2, 3], "x_um": [1.0, 2.0, 3.0], "y_um": [1.0] * 3,
                           "z_um": [9.0, math.nan, 9.0], "alpha": [0.8] * 3,
                           "status": ["ok", "failed", "ok"]}).set_index("frame", drop=False)
    library = pd.DataFrame({"frame": [0, 3], "c1_psi_rad": [0.1, math.nan],
                            "c1_theta_rad": [0.2, math.nan], "c1_phi_rad": [0.0, math.nan],
                            "c1_r2": [0.9, math.nan], "status": ["ok", "error"]}
                           ).set_index("frame", drop=False)
    load = FrameLoader(_Crops(), prefit, library)
    skipped = load(1)
    assert isinstance(skipped, Precomputed)
    assert skipped.row["message"] == "crop stage: no_particle: nothing found"
    assert load(2).row["message"] == "prefit: its z_um missing (status failed)"
    assert load(3).row["message"] == "library: no candidate (status error)"
    got = load(0)
    assert isinstance(got, FrameStart)
    assert got.corner == (10, 20) and got.crop[0, 0] == 0.0
    assert got.start == {"x_um": 1.0, "y_um": 1.0, "z_um": 9.0, "alpha": 0.8}
    assert got.candidates == [(0.1, 0.2, 0.0, 0.9)]
    # without prefit and library tables only the crop rule applies
    assert isinstance(FrameLoader(_Crops())(2), FrameStart)


def test_crop_rows_without_a_centre_are_skipped():
    row = {"status": "edge", "x_um": 1.0, "y_um": math.nan, "corner_row": 3, "corner_col": None}
    skip = crop_skip(row)
    assert skip is not None and skip.row["status"] == "skipped"
    assert skip.row["message"] == "crop table has no y_um, corner_col for this frame"
    assert crop_skip({"status": "ok", "x_um": 1, "y_um": 2, "corner_row": 3,
                      "corner_col": 4}) is None
