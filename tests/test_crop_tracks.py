"""Linking hologram centres into tracks (holofit.crop.tracks) against simulated truth."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from holofit.crop.tracks import LinkSettings, TrackError, link_tracks, mark_neighbours

PIXEL_UM = 0.12
FRAMES = 300


def _brownian(rng: np.random.Generator, start_px, n: int, step_um: float) -> np.ndarray:
    steps = rng.normal(0.0, step_um / PIXEL_UM, (n, 2))
    steps[0] = 0
    return np.asarray(start_px, dtype=float) + np.cumsum(steps, axis=0)


def _scene(seed: int = 3) -> tuple[pd.DataFrame, dict[int, tuple[int, int]]]:
    """Five particles on a 1024x1280 field; truth id in column ``true``.

    0 and 1 approach to ~2.5 um and part again; 2 drifts out through the right edge at
    frame ~150; 3 enters through the left edge at frame ~120; 4 stays put. 3 % of the
    detections are missed, and one-frame junk candidates appear at random.
    """
    rng = np.random.default_rng(seed)
    t = np.arange(FRAMES)
    step = 0.13  # um per frame per axis: a 1 um sphere at 100 frames/s
    paths = {}
    # 0 and 1 head for each other, closest (~2.5 um) at frame 150, then part
    for pid, sign in ((0, -1.0), (1, 1.0)):
        x = 640 + sign * (1 - t / 150) * 120
        y = 500 + sign * 10.4 + 0 * t
        noise = _brownian(rng, (0, 0), FRAMES, 0.03)
        paths[pid] = (np.c_[x, y] + noise, t)
    x2 = 1100 + t * 1.3
    paths[2] = (_brownian(rng, (0, 0), FRAMES, step) + np.c_[x2, 300 + 0 * t], t)
    x3 = -60 + t * 0.9
    paths[3] = (_brownian(rng, (0, 0), FRAMES, step) + np.c_[x3, 800 + 0 * t], t)
    paths[4] = (_brownian(rng, (300, 200), FRAMES, step), t)
    rows = []
    spans = {}
    for pid, (xy, frames) in paths.items():
        inside = (xy[:, 0] >= 0) & (xy[:, 0] < 1280) & (xy[:, 1] >= 0) & (xy[:, 1] < 1024)
        seen = inside & (rng.random(FRAMES) > 0.03)
        spans[pid] = (int(frames[inside][0]), int(frames[inside][-1]))
        for k in np.nonzero(seen)[0]:
            rows.append((int(frames[k]), xy[k, 0], xy[k, 1], 500.0, pid))
    for k in rng.choice(FRAMES, 12, replace=False):  # junk: one frame each, far from all
        rows.append((int(k), rng.uniform(0, 1280), rng.uniform(900, 1024), 12.0, -1))
    table = pd.DataFrame(rows, columns=["frame", "x_px", "y_px", "score", "true"])
    return table.sample(frac=1.0, random_state=1).reset_index(drop=True), spans


def test_every_track_found_without_identity_swaps():
    candidates, spans = _scene()
    result = link_tracks(candidates, PIXEL_UM, LinkSettings(search_range_um=1.5, memory=3))
    linked = result.candidates
    assert len(result.particles) == 5
    for pid in result.particles:
        truth = linked.loc[linked["particle"] == pid, "true"]
        assert truth.nunique() == 1, f"track {pid} mixes particles {sorted(truth.unique())}"
        true_id = int(truth.iloc[0])
        assert true_id >= 0
        first, last = spans[true_id]
        frames = linked.loc[linked["particle"] == pid, "frame"]
        # one track from entry to exit: the missed detections were bridged by the memory
        assert frames.min() <= first + 3 and frames.max() >= last - 3
    # junk left out, and said why
    dropped = result.summary[~result.summary["kept"].astype(bool)]
    assert len(dropped) == 12
    assert dropped["reason"].str.contains("min_track_length").all()
    assert (linked["true"] >= 0).all()


def test_ids_follow_first_appearance_and_are_reproducible():
    candidates, _ = _scene()
    a = link_tracks(candidates, PIXEL_UM)
    b = link_tracks(candidates.sample(frac=1.0, random_state=7), PIXEL_UM)
    kept = a.summary[a.summary["kept"].astype(bool)]
    assert list(kept["particle"]) == list(range(len(kept)))
    assert kept["first_frame"].is_monotonic_increasing
    pd.testing.assert_frame_equal(
        a.candidates[["particle", "frame", "x_px"]], b.candidates[["particle", "frame", "x_px"]]
    )


def test_max_particles_keeps_the_longest():
    candidates, spans = _scene()
    result = link_tracks(candidates, PIXEL_UM, LinkSettings(max_particles=2))
    assert len(result.particles) == 2
    kept_truth = set(result.candidates["true"].unique())
    lengths = {pid: spans[pid][1] - spans[pid][0] for pid in spans}
    # the two full-length tracks among 0, 1, 4 (2 leaves, 3 enters)
    assert kept_truth <= {0, 1, 4} and all(lengths[p] == FRAMES - 1 for p in kept_truth)
    assert result.summary["reason"].str.contains("max_particles").sum() == 3


def test_neighbours_mark_the_close_approach():
    candidates, _ = _scene()
    linked = mark_neighbours(link_tracks(candidates, PIXEL_UM).candidates)
    pair = linked[linked["true"].isin([0, 1]) & (linked["frame"] == 150)]
    assert len(pair) == 2  # both detected in that frame (seed 3)
    gap = np.hypot(*(pair[["x_px", "y_px"]].to_numpy()[0] - pair[["x_px", "y_px"]].to_numpy()[1]))
    assert gap * PIXEL_UM < 3.0  # the close approach the scene was made for
    assert pair["neighbour_px"].to_numpy() == pytest.approx([gap, gap])
    assert set(pair["neighbour"]) == set(pair["particle"])
    alone = linked[linked["true"] == 4]
    assert (alone["neighbour_px"] > 100).all()
    with pytest.raises(TrackError, match="more than one row in frame"):
        mark_neighbours(pd.concat([linked, linked.iloc[:1]]))


def test_bad_input_is_named():
    with pytest.raises(TrackError, match="lacks the column"):
        link_tracks(pd.DataFrame({"frame": [0], "x_px": [1.0]}), PIXEL_UM)
    with pytest.raises(TrackError, match="frame 4"):
        link_tracks(pd.DataFrame({"frame": [4], "x_px": [np.nan], "y_px": [1.0]}), PIXEL_UM)
    with pytest.raises(TrackError, match="search_range_um"):
        LinkSettings(search_range_um=0)
    empty = link_tracks(pd.DataFrame({"frame": [], "x_px": [], "y_px": []}), PIXEL_UM)
    assert empty.particles == [] and empty.summary.empty


def _merging_pair(gap: int) -> pd.DataFrame:
    """Two still spheres 20 px (2.4 um) apart whose holograms give one detection for ``gap``
    frames (closer than the centre finder resolves); the merged centre drifts from nearer
    the left sphere to nearer the right one, as it does when the pair turns about itself."""
    rows = []
    rng = np.random.default_rng(5)
    for f in range(60):
        merged = 20 <= f < 20 + gap
        if merged:
            rows.append((f, 508.0 + 6.0 * (f - 20) / max(gap - 1, 1), 300.0, -1))
            continue
        rows.append((f, 500.0 + rng.normal(0, 0.3), 300.0 + rng.normal(0, 0.3), 0))
        rows.append((f, 520.0 + rng.normal(0, 0.3), 300.0 + rng.normal(0, 0.3), 1))
    return pd.DataFrame(rows, columns=["frame", "x_px", "y_px", "true"])


def test_default_memory_outlives_a_merged_pair_without_a_swap():
    candidates = _merging_pair(gap=8)
    for options, mixes in ((LinkSettings(memory=3), True), (LinkSettings(), False)):
        linked = link_tracks(candidates, PIXEL_UM, options).candidates
        known = linked[linked["true"] >= 0]
        mixed = known.groupby("particle")["true"].nunique().max() > 1
        # with a memory shorter than the gap, the merged detection's track carries on with the
        # right sphere once they part: the swap the default's longer memory prevents
        assert mixed == mixes, f"memory {options.memory}"
    assert LinkSettings().memory >= 10
