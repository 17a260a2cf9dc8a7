"""The file layout of a stage's table (:mod:`holofit.batch.layout`): a derived table published
atomically with its fingerprint, read back, and its files removed, without the stage naming
the journal or the partial table."""

from __future__ import annotations

import json

import pandas as pd
import pytest

from holofit.batch import (
    BatchError,
    BatchSettings,
    discard_outputs,
    journal_path,
    partial_path,
    publish_table,
    published_fingerprint,
    run_batch,
)
from tests.batch_helpers import ToyConfig, toy_frame, toy_payload, toy_table


def test_publish_table_stages_then_renames_the_table_last(tmp_path):
    path = tmp_path / "fit.csv"
    table = pd.DataFrame({"frame": [0, 1, 2], "status": "ok", "message": ""})
    seen = []

    def before(staged):
        seen.append((staged, path.exists(), pd.read_csv(staged)["frame"].tolist()))

    assert publish_table(path, table, {"kind": "toy"}, "abc", before_publish=before) == path
    assert seen == [(partial_path(path), False, [0, 1, 2])]
    doc = json.loads((tmp_path / "fit.csv.json").read_text())
    assert doc["kind"] == "toy"
    assert doc["batch"] == {"fingerprint": "abc", "complete": True, "frames_total": 3}
    assert not partial_path(path).exists()
    assert not (tmp_path / "fit.partial.csv.json").exists()
    assert published_fingerprint(path) == "abc"
    assert (tmp_path / "fit.csv").stat().st_mtime_ns >= (tmp_path / "fit.csv.json").stat(
    ).st_mtime_ns


def test_an_interrupted_publish_leaves_no_table(tmp_path):
    path = tmp_path / "fit.csv"

    def interrupted(staged):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        publish_table(path, pd.DataFrame({"frame": [0]}), {}, "abc", interrupted)
    assert not path.exists() and published_fingerprint(path) is None


def test_published_fingerprint_of_no_table_or_no_sidecar(tmp_path):
    path = tmp_path / "t.csv"
    assert published_fingerprint(path) is None
    path.write_text("frame\n0\n")
    assert published_fingerprint(path) is None
    (tmp_path / "t.csv.json").write_text("not json")
    assert published_fingerprint(path) is None


def test_a_batch_table_has_its_fingerprint_and_discard_outputs_removes_every_file(tmp_path):
    out = tmp_path / "table.csv"
    cfg = ToyConfig(fail_frames=tuple(range(6)))
    opts = BatchSettings(workers=0, progress=False)
    with pytest.raises(BatchError):  # every frame failed: journal and partial table stay
        run_batch(toy_frame, cfg, range(6), toy_payload, toy_table(out), options=opts)
    assert journal_path(out).exists() and partial_path(out).exists()
    discard_outputs(out)
    assert sorted(p.name for p in tmp_path.iterdir()) == []
    run_batch(toy_frame, ToyConfig(), range(6), toy_payload, toy_table(out), options=opts)
    assert published_fingerprint(out) == "toy"
    discard_outputs(out)
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_replace_stale_discards_results_of_other_settings_instead_of_refusing(tmp_path):
    out = tmp_path / "table.csv"
    opts = BatchSettings(workers=0, progress=False)
    run_batch(toy_frame, ToyConfig(), range(3), toy_payload, toy_table(out, fingerprint="a"),
              options=opts)
    with pytest.raises(BatchError, match="other settings"):
        run_batch(toy_frame, ToyConfig(), range(3), toy_payload,
                  toy_table(out, fingerprint="b"), options=opts)
    summary = run_batch(toy_frame, ToyConfig(), range(3), toy_payload,
                        toy_table(out, fingerprint="b", replace_stale=True), options=opts)
    assert summary.n_run == 3 and published_fingerprint(out) == "b"
