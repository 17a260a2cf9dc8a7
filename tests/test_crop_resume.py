"""The crop stage through the batch runner: frames searched in worker processes give the
outputs of a run in this process, and an interrupted run, run again, searches only the frames
it had not searched and ends with the outputs of an uninterrupted run."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
import tifffile

import holofit.crop.detect as detect_module
from holofit.batch import BatchSettings, journal_path, published_fingerprint
from holofit.batch.journal import read_journal
from holofit.crop import CropConfig, run_crop
from tests.test_crop_run import _outputs, simulated  # noqa: F401 (fixture)
from tests.test_crop_synthetic import INSTRUMENT

FILES = ("crops.csv", "candidates.csv", "crops.csv.json", "candidates.csv.json",
         "crops.tif.json")


def _snapshot(out):
    docs = {}
    for name in FILES:
        text = (out / name).read_text()
        if name.endswith(".json"):
            doc = json.loads(text)
            doc.pop("created", None)
            doc.pop("provenance", None)
            text = json.dumps(doc, sort_keys=True)
        docs[name] = text
    return docs, tifffile.imread(out / "crops.tif")


def _same(a, b):
    assert a[0].keys() == b[0].keys()
    for name in a[0]:
        if name.endswith(".json"):
            da, db = json.loads(a[0][name]), json.loads(b[0][name])
            for d in (da, db):  # where the folder is, and when it was made, may differ
                d.pop("outputs", None)
            assert da == db, name
        else:
            assert a[0][name] == b[0][name], name
    np.testing.assert_array_equal(a[1], b[1])


def _run(folder, background, out, batch=None, **kw):
    return run_crop(folder / "movie.tif", background, INSTRUMENT, out, CropConfig(size=100, **kw),
                    batch=batch)


def test_workers_give_the_outputs_of_a_run_in_this_process(simulated, tmp_path):  # noqa: F811
    folder, background, _, _ = simulated
    serial = _run(folder, background, tmp_path / "serial", plot=False)
    pool = _run(folder, background, tmp_path / "pool", plot=False,
                batch=BatchSettings(workers=2, progress=False))
    pd.testing.assert_frame_equal(serial.frames, pool.frames)
    _same(_snapshot(tmp_path / "serial"), _snapshot(tmp_path / "pool"))
    assert "detections.csv" not in _outputs(tmp_path / "pool")


def test_interrupted_crop_resumes_where_it_stopped(simulated, tmp_path, monkeypatch):  # noqa: F811
    folder, background, _, _ = simulated
    whole = _run(folder, background, tmp_path / "whole", plot=False)
    searched: list[int] = []
    real = detect_module.detect

    def counting(movie, k, normalizer, finder):
        if k == 6 and not searched.count(-1):
            searched.append(-1)
            raise KeyboardInterrupt  # killed while searching frame 6
        searched.append(k)
        return real(movie, k, normalizer, finder)

    monkeypatch.setattr(detect_module, "detect", counting)
    out = tmp_path / "out"
    with pytest.raises(KeyboardInterrupt):
        _run(folder, background, out, plot=False)
    assert "crops.csv" not in _outputs(out)
    _, kept, _ = read_journal(journal_path(out / "detections.csv"))
    assert set(range(6)) <= set(kept) and 6 not in kept
    searched.clear()
    searched.append(-1)  # no second interruption
    again = _run(folder, background, out, plot=False)
    # only the frames the interrupted run had not recorded are searched again
    assert sorted(searched[1:]) == sorted(set(range(10)) - set(kept))
    pd.testing.assert_frame_equal(again.frames, whole.frames)
    _same(_snapshot(tmp_path / "whole"), _snapshot(out))
    assert "detections.csv" not in _outputs(out) and "detections.csv.journal" not in _outputs(out)


def test_the_crop_table_is_published_with_its_fingerprint(simulated, tmp_path):  # noqa: F811
    folder, background, _, _ = simulated
    first = _run(folder, background, tmp_path / "a", plot=False)
    key = published_fingerprint(first.table)
    assert key and key == published_fingerprint(_run(folder, background, tmp_path / "b",
                                                     plot=False).table)
    other = _run(folder, background, tmp_path / "c", plot=False, max_jump_px=7.0)
    assert published_fingerprint(other.table) not in (None, key)
    assert not (tmp_path / "a" / "crops.partial.csv").exists()
