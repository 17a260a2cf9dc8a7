"""Multi-row items (a chunk of a track fitted in one go): every row reaches the table keyed by
(chunk, frame); a rerun after an interruption redoes only the chunks that had not finished,
and a chunk whose rows are all in the journal is finished."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest

from holofit.batch import BatchSettings, StageTable, journal_path, run_batch
from holofit.batch.journal import read_journal
from holofit.batch.keys import item_rows

COLUMNS = ("chunk", "frame", "value", "status", "message")
KEYS = ("chunk", "frame")
#: three chunks of frames 0-5, 4-9, 8-11 (overlaps of 2)
CHUNKS = {0: range(0, 6), 1: range(4, 10), 2: range(8, 12)}


class Stop(Exception):
    """The test's interruption."""


def chunk_item(config: dict, key: tuple[int, int], payload: list[int]) -> list[dict]:
    chunk, _ = key
    log = Path(config["log"])
    if chunk in config.get("stop", ()):
        raise KeyboardInterrupt  # an interruption, not an item error
    with log.open("a") as fh:
        fh.write(f"{chunk}\n")
    return [{"chunk": chunk, "frame": f, "value": 10.0 * chunk + f, "status": "ok",
             "message": ""} for f in payload]


def _load(key: tuple[int, int]) -> list[int]:
    return list(CHUNKS[key[0]])


def _run(out: Path, config: dict) -> object:
    return run_batch(chunk_item, config, [(c, r.start) for c, r in CHUNKS.items()], _load,
                     StageTable(out, COLUMNS, {}, "chunks-1", "chunks", key_columns=KEYS),
                     options=BatchSettings(workers=0, progress=False))


def test_item_rows_put_the_items_own_row_last():
    rows = [{"chunk": 1, "frame": f} for f in (4, 5, 6)]
    assert [r["frame"] for r in item_rows(rows, (1, 4), KEYS)] == [5, 6, 4]
    with pytest.raises(ValueError, match="none of its"):
        item_rows(rows, (1, 7), KEYS)
    with pytest.raises(ValueError, match="two rows"):
        item_rows([*rows, {"chunk": 1, "frame": 5}], (1, 4), KEYS)


def test_every_row_of_every_chunk_in_the_table(tmp_path):
    out = tmp_path / "chunks.csv"
    summary = _run(out, {"log": str(tmp_path / "log")})
    table = pd.read_csv(out)
    want = [(c, f) for c, r in CHUNKS.items() for f in r]
    assert list(zip(table["chunk"], table["frame"], strict=True)) == want
    assert table["value"].tolist() == [10.0 * c + f for c, f in want]
    assert summary.statuses == {"ok": 3} and summary.n_run == 3


def test_resume_redoes_only_unfinished_chunks(tmp_path):
    out = tmp_path / "chunks.csv"
    log = tmp_path / "log"
    with pytest.raises(KeyboardInterrupt):
        _run(out, {"log": str(log), "stop": (1,)})
    _, rows, _ = read_journal(journal_path(out), KEYS)
    done = sorted({c for c, _ in rows})
    assert 0 in done and 1 not in done
    # every chunk in the journal is there whole
    assert sorted(rows) == [(c, f) for c in done for f in CHUNKS[c]]
    ran = log.read_text().split()
    assert sorted(int(c) for c in ran) == done
    summary = _run(out, {"log": str(log)})
    again = log.read_text().split()[len(ran):]
    assert sorted(int(c) for c in again) == [c for c in CHUNKS if c not in done]  # none redone
    assert summary.n_done_before == len(done) and summary.n_run == 3 - len(done)
    assert len(pd.read_csv(out)) == sum(len(r) for r in CHUNKS.values())


def test_a_failed_chunk_is_one_error_row_and_is_retried(tmp_path):
    out = tmp_path / "chunks.csv"
    log = tmp_path / "log"

    summary = run_batch(_failing_chunk, {"log": str(log)}, [(c, r.start) for c, r in
                                                             CHUNKS.items()], _load,
                        StageTable(out, COLUMNS, {}, "chunks-2", "chunks", key_columns=KEYS),
                        options=BatchSettings(workers=0, progress=False))
    table = pd.read_csv(out)
    bad = table[table["chunk"] == 1]
    assert len(bad) == 1 and bad["frame"].tolist() == [4] and bad["status"].tolist() == ["error"]
    assert "chunk 1 broke" in bad["message"].iloc[0]
    assert summary.statuses == {"ok": 2, "error": 1}


def _failing_chunk(config: dict, key: tuple[int, int], payload: list[int]) -> list[dict]:
    if key[0] == 1:
        raise RuntimeError("chunk 1 broke")
    return chunk_item(config, key, payload)
