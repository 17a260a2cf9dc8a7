"""Reading crop folders: the crop stage's output contract, and clear errors."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from holofit.config import load_instrument
from holofit.io.tiffstack import write_tiff_stack
from holofit.tables.cropset import CropSet, CropSetError, instrument_from_dict
from tests.conftest import CONFIGS
from tests.prefit_helpers import cut_crop, make_crops_from_frame, write_crop_dir

INST = load_instrument(CONFIGS / "instruments" / "holopy_image0001.toml")


def _crop_dir(tmp_path):
    frame = np.arange(60 * 80, dtype=float).reshape(60, 80)
    return make_crops_from_frame(frame, (40.4, 30.6), 20, INST, tmp_path / "c")


def test_instrument_round_trips_through_the_sidecar(tmp_path):
    got = instrument_from_dict(INST.as_dict())
    assert got == INST  # compares wavelength, index, pixel, polarisation, bit depth, ...
    with CropSet(_crop_dir(tmp_path)) as crops:
        assert crops.instrument == INST
        assert crops.frames == [0] and crops.crop_shape == (20, 20)
        row = crops.row(0)
        assert (row["corner_row"], row["corner_col"]) == (21, 30) and row["status"] == "ok"
        # the crop holds the frame's pixels from the corner on
        assert crops.crop(0)[0, 0] == 21 * 80 + 30


def test_instrument_errors_name_the_file_and_key(tmp_path):
    bad = {**INST.as_dict(), "wavelength_um": 658.0}
    with pytest.raises(ValueError, match=r"sidecar\.json.*wavelength_um.*nanometres"):
        instrument_from_dict(bad, "sidecar.json")


def test_cut_crop_pads_with_nan_at_the_frame_edge():
    frame = np.ones((30, 30))
    crop, corner, status = cut_crop(frame, (2.2, 15.0), 10)
    assert corner == (10, -3) and status == "edge"
    assert np.isnan(crop[:, :3]).all() and (crop[:, 3:] == 1).all()


def test_missing_files_and_inconsistent_folders_are_reported(tmp_path):
    with pytest.raises(CropSetError, match=r"crops\.tif: not found"):
        CropSet(tmp_path)
    d = _crop_dir(tmp_path)
    # two pages for one table row
    write_tiff_stack(d / "crops.tif", [np.ones((20, 20), np.float32)] * 2)
    with pytest.raises(CropSetError, match="2 crop"):
        CropSet(d)
    d2 = write_crop_dir(tmp_path / "d2", [np.ones((5, 5))], [{"frame": 0}], INST)
    table = pd.read_csv(d2 / "crops.csv").drop(columns=["corner_row"])
    table.to_csv(d2 / "crops.csv", index=False)
    with pytest.raises(CropSetError, match=r"missing column.*corner_row"):
        CropSet(d2)


def test_a_folder_without_instrument_has_none(tmp_path):
    d = _crop_dir(tmp_path)
    side = d / "crops.csv.json"
    doc = json.loads(side.read_text())
    doc["config"] = {}
    side.write_text(json.dumps(doc))
    with CropSet(d) as crops:
        assert crops.instrument is None
