"""The item key of a batch: a table keyed by several columns, e.g. (particle, frame), runs,
resumes and completes through the same runner as a per-frame table."""

from __future__ import annotations

import pandas as pd
import pytest

from holofit.batch import BatchSettings, journal_path, run_batch
from holofit.batch.journal import read_journal
from holofit.batch.keys import FRAME_KEY, key_of_row, key_row, normal_key
from tests.batch_helpers import PAIR_COLUMNS, ToyConfig, pair_item, toy_table

KEYS = [(p, f) for p in (0, 1, 2) for f in range(4)]
KEY_COLUMNS = ("particle", "frame")


def _payload(key):
    particle, frame = key
    return 100.0 * particle + frame


def _run(out, config, keys=KEYS, **opts):
    return run_batch(pair_item, config, keys, _payload,
                     toy_table(out, PAIR_COLUMNS, "pairs-1", desc="pairs",
                               key_columns=KEY_COLUMNS),
                     options=BatchSettings(workers=0, progress=False, **opts))


def test_keys_normalised_and_written_back():
    assert normal_key(3.0, FRAME_KEY) == 3 and isinstance(normal_key(3.0, FRAME_KEY), int)
    assert normal_key((2, 5), KEY_COLUMNS) == (2, 5)
    assert key_row((2, 5), KEY_COLUMNS) == {"particle": 2, "frame": 5}
    assert key_of_row({"particle": 2.0, "frame": 5, "x": 1}, KEY_COLUMNS) == (2, 5)
    with pytest.raises(ValueError, match="does not match key columns"):
        normal_key(5, KEY_COLUMNS)


def test_table_keyed_by_particle_and_frame(tmp_path):
    out = tmp_path / "pairs.csv"
    summary = _run(out, ToyConfig())
    table = pd.read_csv(out)
    assert list(table.columns) == list(PAIR_COLUMNS)
    assert list(zip(table["particle"], table["frame"], strict=True)) == KEYS  # sorted by key
    assert table["value"].tolist() == [_payload(k) for k in KEYS]
    assert summary.statuses == {"ok": len(KEYS)}


def test_rerun_runs_only_the_items_in_error(tmp_path):
    out = tmp_path / "pairs.csv"
    log = tmp_path / "log"
    log.mkdir()
    with pytest.raises(Exception, match="bad item"):  # particle 1 fails everywhere...
        _run(out, ToyConfig(fail_frames=(0, 1, 2, 3)), keys=[k for k in KEYS if k[0] == 1])
    # ... the journal holds its rows keyed by (particle, frame)
    header, rows, _ = read_journal(journal_path(out))
    assert header["key_columns"] == list(KEY_COLUMNS)
    assert sorted(rows) == [(1, f) for f in range(4)]
    # a rerun with the cause fixed runs exactly those items again, and the rest
    _run(out, ToyConfig(log_dir=str(log)), keys=[k for k in KEYS if k[0] == 1])
    called = sorted(line for p in log.iterdir() for line in p.read_text().split())
    assert called == sorted(f"1,{f}" for f in range(4))
    table = pd.read_csv(out)
    assert (table["status"] == "ok").all() and table["particle"].eq(1).all()
