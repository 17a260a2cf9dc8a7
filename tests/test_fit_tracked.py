"""The followed final pass's chunks: every frame in a chunk, neighbours overlapping, the plan
independent of the workers; stitching a chunk table (a failed chunk's frames are errors)."""

from __future__ import annotations

import itertools

import pandas as pd

from holofit.fit.chunks import (
    INITIAL_OVERLAP,
    MAX_CHUNK,
    OVERLAP,
    consecutive_runs,
    plan_chunks,
    stitch_table,
)
from holofit.io.tables import read_table, write_table


def test_chunks_cover_every_frame_and_overlap():
    for n in (1, 5, 24, 500, 2000, 2001):
        frames = list(range(10, 10 + n))
        chunks = plan_chunks(frames)
        assert sorted({f for c in chunks for f in c}) == frames
        assert all(len(c) <= MAX_CHUNK + OVERLAP for c in chunks)
        for a, b in itertools.pairwise(chunks):
            assert a[-OVERLAP:] == b[:OVERLAP]  # each reaches into the next
    assert len(plan_chunks(range(24))) == 2  # a short movie still shared by workers
    assert len(plan_chunks(range(2000))) == 20
    assert plan_chunks([]) == []
    initial = plan_chunks(range(100), INITIAL_OVERLAP)  # the initial pass: no overlap
    assert all(a[-1] + 1 == b[0] for a, b in itertools.pairwise(initial))
    assert sum(len(c) for c in initial) == 100
    # the initial pass's default 8 frames: one chunk of 4 per worker
    assert [len(c) for c in plan_chunks(range(8), INITIAL_OVERLAP, min_chunk=4)] == [4, 4]


def test_the_initial_passs_frames_are_cut_into_their_runs():
    from holofit.fit.initial_pass import initial_choice

    assert consecutive_runs([]) == []
    assert consecutive_runs([5, 1, 2, 3, 9, 10]) == [[1, 2, 3], [5], [9, 10]]
    # a frame that cannot be fitted (2) cuts the run: no warm fit across the gap
    chosen = initial_choice([0, 1, 3, 4, 5, 6], [False] * 6, 4)
    assert chosen == [0, 1, 3, 4]
    assert consecutive_runs(chosen) == [[0, 1], [3, 4]]


def _row(chunk, frame, x, status="ok", message=""):
    return {"particle": 0, "chunk": chunk, "frame": frame, "x_um": x, "y_um": 0.0, "z_um": 5.0,
            "ux": 0.0, "uy": 0.0, "uz": 1.0, "chi2": 10.0 + x, "status": status,
            "message": message}


def test_stitch_keeps_the_earlier_row_and_fills_a_failed_chunk(tmp_path):
    chunks = [[0, 1, 2, 3], [2, 3, 4, 5], [4, 5, 6]]
    rows = [_row(0, f, 0.0) for f in chunks[0]]
    rows += [_row(1, 2, 0.0), _row(1, 3, 0.5)]  # frame 3 disagrees (0.5 um), worse chi2
    rows += [_row(1, f, 0.0) for f in (4, 5)]
    rows += [_row(2, 4, 0.0, "error", "RuntimeError: broke")]  # chunk 2 failed whole
    path = tmp_path / "chunks.csv"
    write_table(path, pd.DataFrame(rows))
    table, bad = stitch_table(read_table(path), {0: chunks}, head_tail=True)
    assert table["frame"].tolist() == list(range(7))
    assert table.set_index("frame").loc[3, "x_um"] == 0.0  # the earlier (better) kept
    assert bad["frame"].tolist() == [3] and bad["kept"].tolist() == ["earlier"]
    six = table.set_index("frame").loc[6]
    assert six["status"] == "error" and "chunk 2 (frames 4-6)" in six["message"]
    assert table.set_index("frame").loc[4, "status"] == "ok"  # chunk 1 reached it
