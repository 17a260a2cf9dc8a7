"""Following a track (holofit.fit.follow) on simulated rod tracks of known truth:
warm frames land where independent fits do at a fraction of the cost, a track started on the
wrong branch and a track whose particle jumps (a frame dropped) recover by re-acquisition with
the frames in between flagged, the runner-up keeps its meaning, chunks stitch; a frame with an
initial-pass row is checked against it: a wrong-branch warm frame is switched to the right
branch, right-branch frames are left exactly as they were."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from holofit.fit.chunks import stitch_chunks
from holofit.fit.follow import chunk_fitter, follow_chunk
from holofit.fit.frame import fit_frame
from holofit.fit.problem import FrameProblem, state_of
from holofit.fit.settings import FollowSettings, FrameFitSettings
from holofit.fit.warm import fit_frame_warm
from holofit.library.search import Candidate
from tests.tracking_helpers import FINAL, INSTRUMENT, JANUS, ROD, engine, make_track

OPTICS = INSTRUMENT.optics
PX = INSTRUMENT.pixel_size_um


@pytest.fixture(scope="module")
def theory():
    return engine()


def _track(theory, track, bar=None, options=None, start=None):
    return follow_chunk(track.frames, chunk_fitter(theory, ROD, OPTICS, PX, FINAL, options), bar,
                        start)


def _right(track, row, k, nm=20.0, deg=2.0) -> bool:
    return track.position_error_um(row, k) < nm * 1e-3 and track.axis_error_deg(row, k) < deg


def _flagged(row) -> bool:
    return row["status"] != "ok" or row["ambiguous"] == 1 or row["follow_jump"] == 1


def test_warm_frames_follow_the_rod_at_a_fraction_of_the_cost(theory):
    track = make_track(theory, n=6, seed=0)
    tab = _track(theory, track)
    rows = tab.to_dict("records")
    assert [r["follow_source"] for r in rows] == ["library"] + ["warm"] * 5
    for k, row in enumerate(rows):
        assert row["status"] == "ok", row["message"]
        assert _right(track, row, k), (k, track.position_error_um(row, k),
                                       track.axis_error_deg(row, k))
        assert row["follow_jump"] == 0 and row["ambiguous"] == 0
    warm = tab[tab["follow_source"] == "warm"]
    # each warm frame: one fit from the last (~4-5 iterations) and a runner-up looked at
    assert warm["n_eval"].mean() < 0.4 * rows[0]["n_eval"]
    # the mirror runner-up is a real minimum: decisive here, and its delta is reported
    assert (warm["delta_chi2"] > 100).all()


def test_independent_frames_are_todays_fit_frame(theory):
    track = make_track(theory, n=2, seed=3)
    tab = _track(theory, track, options=FollowSettings(warm=False))
    for f, row in zip(track.frames, tab.to_dict("records"), strict=True):
        ref = fit_frame(
            FrameProblem(
                f.crop,
                f.corner,
                PX,
                theory,
                ROD,
                OPTICS,
                FINAL,
                settings=FrameFitSettings(),
                seed=f.frame,
            ),
            f.position_um,
            f.alpha,
            f.candidates,
        )
        assert row["follow_source"] == "library"
        for key, value in ref.values.items():
            assert row[key] == value, key
        assert row["chi2"] == ref.chi2 and row["n_eval"] == ref.n_eval
        assert row["delta_chi2"] == ref.extra["delta_chi2"] or (
            math.isnan(row["delta_chi2"]) and math.isnan(ref.extra["delta_chi2"])
        )


def test_warm_fit_from_the_truth_lands_where_the_library_fit_does(theory):
    track = make_track(theory, n=1, seed=4)
    f = track.frames[0]
    ref = fit_frame(
        FrameProblem(
            f.crop,
            f.corner,
            PX,
            theory,
            ROD,
            OPTICS,
            FINAL,
            settings=FrameFitSettings(),
            seed=0,
        ),
        f.position_um,
        f.alpha,
        f.candidates,
    )
    truth = {
        "x_um": track.positions[0][0],
        "y_um": track.positions[0][1],
        "z_um": track.positions[0][2],
        "psi_rad": track.angles[0, 0],
        "theta_rad": track.angles[0, 1],
        "alpha": 0.9,
    }
    warm = fit_frame_warm(
        FrameProblem(
            f.crop,
            f.corner,
            PX,
            theory,
            ROD,
            OPTICS,
            FINAL,
            settings=FrameFitSettings(),
            seed=0,
        ),
        state_of(truth, ROD),
    ).result
    assert warm.status == "ok"
    assert abs(warm.chi2_red - ref.chi2_red) < 1e-3 * ref.chi2_red
    for key in ("x_um", "y_um", "z_um"):
        assert abs(warm.values[key] - ref.values[key]) < 2e-3, key
    assert warm.extra["runner_up_refit"] == 1  # nothing carried: the mirror was screened
    assert warm.extra["delta_chi2"] > 100 and warm.extra["ambiguous"] == 0


def test_a_track_started_on_the_wrong_branch_recovers_and_flags_the_frames_between(theory):
    track = make_track(theory, n=5, seed=1)
    wrong = {
        "x_um": track.positions[0][0],
        "y_um": track.positions[0][1],
        "z_um": track.positions[0][2] + 0.1,
        "psi_rad": track.angles[0, 0],
        "theta_rad": math.pi - track.angles[0, 1],
        "alpha": 0.9,
    }
    tab = _track(theory, track, start=wrong)
    rows = tab.to_dict("records")
    for k, row in enumerate(rows):  # no frame on the wrong branch is ok and unflagged
        assert _right(track, row, k) or _flagged(row), (k, row["message"])
    # the first frame is taken from the library, flagged as a jump from the wrong start
    assert rows[0]["follow_source"] == "reacquired" and rows[0]["follow_jump"] == 1
    assert "jump" in rows[0]["message"]
    for k, row in enumerate(rows[1:], start=1):
        assert row["follow_source"] == "warm" and row["status"] == "ok"
        assert _right(track, row, k)


def test_a_dropped_frame_jump_is_reacquired_and_flagged(theory):
    track = make_track(theory, n=7, seed=2, jump_at=4, dropped=1)
    tab = _track(theory, track)
    rows = tab.to_dict("records")
    assert [r["frame"] for r in rows] == [0, 1, 2, 3, 5, 6, 7]
    jump = rows[4]
    assert jump["follow_source"] == "reacquired" and jump["follow_jump"] == 1
    assert "jump" in jump["message"] and "from frame 3" in jump["message"]
    for k, row in enumerate(rows):
        assert _right(track, row, k), k
        if k not in (0, 4):
            assert row["follow_source"] == "warm" and row["follow_jump"] == 0, k


def test_a_mirror_within_the_noise_is_refitted_on_all_pixels(theory):
    # pixel noise taken 60x the camera's: the mirror theta -> pi - theta comes within the
    # refit margin, so it is fitted on all pixels (here it rolls back into the best's own
    # basin: no competing minimum, as today's independent fit finds on the first frame)
    track = make_track(theory, n=4, seed=5)
    tab = _track(theory, track, options=FollowSettings(frame=FrameFitSettings(noise_sd=0.5)))
    warm = tab[tab["follow_source"] == "warm"]
    assert len(warm) == 3 and (warm["runner_up_refit"] == 2).all()
    for row in tab.to_dict("records"):
        assert math.isnan(row["delta_chi2"]) or row["ambiguous"] == int(row["delta_chi2"] < 9)


def test_a_frame_above_the_movies_bar_is_reacquired_and_flagged_poor(theory):
    track = make_track(theory, n=4, seed=6)
    f = track.frames[2]  # a smooth artefact (a neighbour's fringes) on frame 2
    cols = np.arange(f.crop.shape[1])
    stripes = 0.04 * np.sin(2 * np.pi * cols / 9.0)[None, :]
    track.frames[2] = replace(f, crop=f.crop + stripes)
    tab = _track(theory, track, bar=1.5)
    rows = tab.to_dict("records")
    assert [r["status"] for r in rows] == ["ok", "ok", "poor_fit", "ok"]
    assert rows[2]["follow_source"] == "reacquired" and rows[2]["chi2_red"] > 1.5
    assert "above the movie's bar" in rows[2]["message"]
    # the next frame starts from the last accepted one (frame 1) and is warm again
    assert rows[3]["follow_source"] == "warm" and _right(track, rows[3], 3)


def test_overlapping_chunks_stitch_and_disagreements_are_reported(theory):
    track = make_track(theory, n=5, seed=7)
    first = _track(theory, type(track)(track.frames[:3], track.positions, track.angles))
    second = _track(theory, type(track)(track.frames[1:], track.positions, track.angles))
    table, bad = stitch_chunks([first, second], head_tail=True)
    assert list(table["frame"]) == [0, 1, 2, 3, 4] and bad.empty
    assert table.loc[1, "follow_source"] == "warm"  # the earlier chunk's row is kept
    moved = second.copy()
    moved.loc[0, "x_um"] += 0.1  # frame 1 of the second chunk somewhere else
    table, bad = stitch_chunks([first, moved], head_tail=True)
    assert list(bad["frame"]) == [1]
    assert bad.loc[0, "position_diff_um"] == pytest.approx(0.1, abs=0.03)
    assert np.isfinite(bad.loc[0, "chi2_later"])


@pytest.mark.slow
def test_a_janus_track_started_on_its_mirror_has_no_ok_unflagged_wrong_frame():
    # the Janus mirror (cap toward the camera or the light) is a second minimum: started
    # there, every frame is either back on the right branch or flagged
    theory = engine(JANUS)
    track = make_track(theory, n=6, seed=8, model=JANUS)
    wrong = {
        "x_um": track.positions[0][0],
        "y_um": track.positions[0][1],
        "z_um": track.positions[0][2] + 0.2,
        "psi_rad": track.angles[0, 0],
        "theta_rad": math.pi - track.angles[0, 1],
        "alpha": 0.9,
    }
    tab = follow_chunk(
        track.frames, chunk_fitter(theory, JANUS, OPTICS, PX, FINAL), None, start=wrong
    )
    rows = tab.to_dict("records")
    for k, row in enumerate(rows):
        assert _right(track, row, k, nm=30.0, deg=3.0) or _flagged(row), (k, row["message"])
    assert all(_right(track, r, k, nm=30.0, deg=3.0) for k, r in enumerate(rows) if k >= 1)


def test_a_short_movie_gets_a_bar_and_an_artefact_frame_is_not_ok(theory, tmp_path):
    """A short movie's initial pass has fewer than 10 frames: before, no chi^2 bar, so a warm
    frame off the data was accepted on its status and step alone (plain ``ok``)."""
    from holofit.fit.chunk_task import bar_from_initial
    from holofit.io.tables import write_table

    track = make_track(theory, n=4, seed=6)
    clean = _track(theory, track)  # the few frames an initial pass would give
    assert (clean["status"] == "ok").all()
    write_table(tmp_path / "initial.csv", clean)
    bar, note = bar_from_initial(tmp_path / "initial.csv", 4.0)
    assert bar is not None and "fewer than 10" in note
    assert clean["chi2_red"].max() < bar < 1.2
    f = track.frames[2]  # a faint artefact (a neighbour's fringes) on frame 2
    cols = np.arange(f.crop.shape[1])
    track.frames[2] = replace(f, crop=f.crop + 0.02 * np.sin(2 * np.pi * cols / 9.0)[None, :])
    rows = _track(theory, track, bar=bar).to_dict("records")
    assert rows[2]["chi2_red"] > bar and rows[2]["status"] == "poor_fit"
    assert rows[2]["follow_source"] == "reacquired"
    assert [r["status"] for r in rows[:2] + rows[3:]] == ["ok"] * 3


def _initial_rows(theory, track, frames, model=ROD):
    """The initial pass's rows of ``frames``: independent library fits with the statics free
    (stopping within 1 chi^2 unit, as the stage's initial pass), fitted off this track."""
    from holofit.holomodel.parameters import static_values

    free = (*FINAL, *(name for name, _ in static_values(model)))
    opts = FrameFitSettings(stop_chi2=1.0)
    rows = {}
    for k in frames:
        f = track.frames[k]
        res = fit_frame(
            FrameProblem(
                f.crop,
                f.corner,
                PX,
                theory,
                model,
                OPTICS,
                free,
                settings=opts,
                seed=f.frame,
            ),
            f.position_um,
            f.alpha,
            f.candidates,
        )
        assert res.status == "ok"
        rows[k] = dict(res.values)
    return rows


def test_a_wrong_branch_warm_frame_with_a_right_initial_row_is_switched():
    """A Janus track that ran onto a wrong branch stays there, plain ``ok``, until a frame has
    an initial-pass row; there the row's pose beats the warm fit by far more than the margin,
    the frame is refitted from it and re-acquired (flagged: a jump from the wrong branch), and
    the track goes on from it on the right branch.

    The wrong branch is the mirror, started from; the warm fits' runner-up (which would find
    the mirror) is off, standing for a competing minimum no runner-up looks at (the 24-frame
    Janus movie's frame 2 was psi-off); the bar (2.0) is loose enough that the wrong branch
    is under it, as that frame's chi^2_red 1.076 was under its movie's bar 1.081. Before the
    check, frames 2 and 3 stayed on the wrong branch, ``ok`` and unflagged."""
    theory = engine(JANUS)
    track = make_track(theory, n=4, seed=8, model=JANUS)
    initial = _initial_rows(theory, track, [2], JANUS)
    track.frames[2] = replace(track.frames[2], initial=initial[2])
    wrong = {
        "x_um": track.positions[0][0],
        "y_um": track.positions[0][1],
        "z_um": track.positions[0][2] + 0.2,
        "psi_rad": track.angles[0, 0],
        "theta_rad": math.pi - track.angles[0, 1],
        "alpha": 0.9,
    }
    opts = FollowSettings(frame=FrameFitSettings(mirror=False))
    rows = follow_chunk(
        track.frames, chunk_fitter(theory, JANUS, OPTICS, PX, FINAL, opts), 2.0, start=wrong
    ).to_dict("records")

    def right(k):
        return _right(track, rows[k], k, nm=30.0, deg=3.0)

    for k in (0, 1):  # on the wrong branch, nothing here says so (no initial row)
        assert not right(k) and not _flagged(rows[k]), k
        assert rows[k]["follow_initial"] == -1
    two = rows[2]
    assert right(2), (track.axis_error_deg(two, 2), two["message"])
    assert two["follow_initial"] == 2 and two["follow_source"] == "reacquired"
    assert two["follow_initial_dchi2"] > 100 and "initial pass" in two["message"], two["message"]
    assert two["follow_jump"] == 1 and "jump" in two["message"]  # flagged, not plain ok
    assert two["ambiguous"] == 0
    assert rows[3]["follow_source"] == "warm" and right(3) and rows[3]["status"] == "ok"
    assert rows[3]["follow_initial"] == -1


def test_right_branch_frames_with_initial_rows_are_not_changed(theory):
    """Control: on a track that stays on the right branch, the initial rows (fitted with
    their own statics) never beat the warm fits: the rows are those of the track without
    them, at one hologram evaluation each."""
    track = make_track(theory, n=5, seed=0)
    plain = _track(theory, track).to_dict("records")
    initial = _initial_rows(theory, track, [0, 2, 4])
    for k, values in initial.items():
        track.frames[k] = replace(track.frames[k], initial=values)
    rows = _track(theory, track).to_dict("records")
    for k, (a, b) in enumerate(zip(plain, rows, strict=True)):
        assert b["status"] == "ok" and _right(track, b, k)
        assert b["follow_source"] == a["follow_source"]
        for key in ("x_um", "y_um", "z_um", "theta_rad", "psi_rad", "alpha", "chi2"):
            assert b[key] == a[key], (k, key)
        if k in initial:
            assert b["follow_initial"] == 0 and b["follow_initial_dchi2"] < 9.0
            assert b["n_eval"] == a["n_eval"] + 1
        else:
            assert b["follow_initial"] == -1 and math.isnan(b["follow_initial_dchi2"])
            assert b["n_eval"] == a["n_eval"]  # nothing to check: no cost


def test_a_chunk_opens_at_the_frame_the_library_reads_best_and_reaches_the_rest_warm(theory):
    """``open_at_best`` (the default): frames 0-1 carry a poor library candidate (R^2
    0.6, 40 deg off, as from a prefit height far off), frame 2 a good one; the chunk opens
    with frame 2's library fit and reaches 1 and 0 warm, backward, onto the truth. Without it
    the chunk opens at frame 0, from its poor candidate."""
    track = make_track(theory, n=5, seed=3)
    poor = (Candidate(track.angles[0, 0] + 0.7, track.angles[0, 1] + 0.7, 0.0, 0.6),)
    frames = list(track.frames)
    for k in (0, 1):
        frames[k] = replace(frames[k], candidates=poor)
    frames[3] = replace(frames[3], candidates=(replace(frames[3].candidates[0], r2=0.9),))
    opened = follow_chunk(
        frames,
        chunk_fitter(theory, ROD, OPTICS, PX, FINAL, FollowSettings(open_at_best=True)),
        None,
    )
    rows = opened.to_dict("records")
    assert [r["frame"] for r in rows] == [0, 1, 2, 3, 4]
    assert [r["follow_source"] for r in rows] == ["warm", "warm", "library", "warm", "warm"]
    for k, row in enumerate(rows):
        assert _right(track, row, k) and row["status"] == "ok", (k, row["message"])
    plain = follow_chunk(
        frames,
        chunk_fitter(theory, ROD, OPTICS, PX, FINAL, FollowSettings(open_at_best=False)),
        None,
    )
    assert plain.loc[0, "follow_source"] == "library"  # the default opens at the first frame
    assert plain.loc[0, "n_eval"] > rows[0]["n_eval"]  # from the poor candidate: dearer


def _single_janus_frame(theory, theta_deg: float, seed: int):
    """One simulated frame of the test Janus particle at polar angle ``theta_deg``."""
    from holofit.camera import Camera
    from holofit.fit.follower import ChunkFrame
    from holofit.simulate.holograms import Exposure, simulate_movie
    from tests.tracking_helpers import BACKGROUND, SHAPE

    rng = np.random.default_rng(seed)
    psi, theta = rng.uniform(-math.pi, math.pi), math.radians(theta_deg)
    pos = np.array([[32.3 * PX, 31.6 * PX, 6.0]])
    movie = simulate_movie(JANUS, INSTRUMENT, pos, SHAPE,
                           orientations=np.array([[psi, theta, 0.0]]), alpha=0.9,
                           theory=theory, seed=seed, keep_frames=True,
                           exposure=Exposure(camera=Camera(background_counts=BACKGROUND)))
    frame = ChunkFrame(
        1,
        movie.frames[0] / BACKGROUND,
        (0, 0),
        tuple(pos[0]),
        0.9,
        (Candidate(psi, theta, 0.0, 0.9),),
        0.01,
    )
    return frame, pos[0], psi, theta


def _axis_off_deg(values, psi: float, theta: float) -> float:
    u = (
        [values["ux"], values["uy"], values["uz"]]
        if "ux" in values
        else [
            math.sin(values["theta_rad"]) * math.cos(values["psi_rad"]),
            math.sin(values["theta_rad"]) * math.sin(values["psi_rad"]),
            math.cos(values["theta_rad"]),
        ]
    )
    ut = [math.sin(theta) * math.cos(psi), math.sin(theta) * math.sin(psi), math.cos(theta)]
    return math.degrees(math.acos(min(1.0, float(np.dot(u, ut)))))


def test_pole_probes_are_tilted_evenly_around_the_axis():
    from holofit.conventions import euler_zyz
    from holofit.fit.rescue import pole_probes
    from holofit.holomodel.parameters import State

    for theta in (0.0, 0.1, 2.5):
        state = State((0.0, 0.0, 5.0), euler_zyz(0.7, theta, 0.0), 0.9, ())
        axis = state.rotation[:, 2]
        probes = pole_probes(state, 6, math.radians(15.0))
        axes = np.array([p.rotation[:, 2] for p in probes])
        assert np.allclose(np.degrees(np.arccos(axes @ axis)), 15.0)
        # evenly around: neighbours equally far apart, opposite ones 30 deg apart
        gaps = [
            math.degrees(math.acos(np.clip(axes[k] @ axes[(k + 1) % 6], -1, 1))) for k in range(6)
        ]
        assert np.allclose(gaps, gaps[0]) and gaps[0] > 14.0
        assert math.isclose(math.degrees(math.acos(axes[0] @ axes[3])), 30.0, abs_tol=1e-6)
        for p in probes:  # proper rotations
            assert np.allclose(p.rotation.T @ p.rotation, np.eye(3), atol=1e-12)


def test_a_fit_held_near_the_pole_is_probed_onto_the_truth():
    """A Janus frame at theta 22 deg whose fit sits at theta 4 deg (its orientation held
    there, as a warm start near the pole holds it on the replicate): the probes tilted 15
    deg from it find the true minimum and the frame is refitted from there, its runner-up
    the nearest competing minimum; with no probes it stays where it was."""
    from holofit.fit.follower import ChunkFitter
    from holofit.fit.rescue import probe_near_pole
    from holofit.fit.warm import fit_frame_warm

    theory = engine(JANUS)
    f, pos, psi, theta = _single_janus_frame(theory, 22.0, seed=5)
    near = state_of(
        {
            "x_um": pos[0],
            "y_um": pos[1],
            "z_um": pos[2],
            "alpha": 0.9,
            "psi_rad": psi + 1.0,
            "theta_rad": math.radians(4.0),
        },
        JANUS,
    )
    held = fit_frame_warm(
        FrameProblem(
            f.crop,
            f.corner,
            PX,
            theory,
            JANUS,
            OPTICS,
            ("x_um", "y_um", "z_um", "alpha"),
            settings=FrameFitSettings(mirror=False),
            seed=1,
        ),
        near,
    ).result
    assert _axis_off_deg(held.values, psi, theta) > 15.0
    fitter = ChunkFitter(theory, JANUS, OPTICS, PX, FINAL, FollowSettings())
    n_before = held.n_eval
    res, _, code = probe_near_pole(fitter, f, held, None)
    assert code == 1
    assert _axis_off_deg(res.values, psi, theta) < 2.0
    assert res.rss < held.rss and "optical axis" in res.message
    assert res.n_eval > n_before + 6  # six probes and the refit counted
    # the runner-up is the nearest competing minimum: the pole fit or one nearer still
    excess = (held.rss - res.rss) / res.noise_sd**2
    assert 9.0 < res.extra["delta_chi2"] <= excess + 1e-6 and res.extra["ambiguous"] == 0
    none = ChunkFitter(theory, JANUS, OPTICS, PX, FINAL, FollowSettings(pole_probes=0))
    same, _, code0 = probe_near_pole(none, f, held, None)
    assert code0 == -1 and same is held


def test_a_right_fit_near_the_pole_is_left_as_it_is():
    """Control: a Janus frame at theta 8 deg fitted from the truth; the probes find nothing
    lower by the margin, and the fit (values and chi^2) is kept as it was; a fit away from
    the pole is not probed at all."""
    from holofit.fit.follower import ChunkFitter
    from holofit.fit.rescue import probe_near_pole
    from holofit.fit.warm import fit_frame_warm

    theory = engine(JANUS)
    fitter = ChunkFitter(theory, JANUS, OPTICS, PX, FINAL, FollowSettings())
    for theta_deg, probed in ((8.0, True), (55.0, False)):
        f, pos, psi, theta = _single_janus_frame(theory, theta_deg, seed=6)
        truth = state_of(
            {
                "x_um": pos[0],
                "y_um": pos[1],
                "z_um": pos[2],
                "alpha": 0.9,
                "psi_rad": psi,
                "theta_rad": theta,
            },
            JANUS,
        )
        fit = fit_frame_warm(
            FrameProblem(f.crop, f.corner, PX, theory, JANUS, OPTICS, FINAL, seed=1), truth
        ).result
        values, rss, n = dict(fit.values), fit.rss, fit.n_eval
        res, _, code = probe_near_pole(fitter, f, fit, None)
        assert code == (0 if probed else -1)
        assert res is fit and res.values == values and res.rss == rss
        assert (res.n_eval > n) == probed


def test_a_warm_fit_on_a_wrong_branch_is_rechecked_from_its_neighbours():
    """A Janus frame at theta 22 deg whose warm fit sits 15+ deg off the truth (held at
    theta 4 deg); its predecessor's and successor's fits are 16 deg from the truth on either
    side (one along theta, one across it), as on a fast-turning replicate: refitted from the
    orientation between them, the frame lands on the truth and the minimum it left becomes its
    runner-up. Controls: a right fit whose successor is as far away is rechecked and kept as
    it was; one whose successor is within ``recheck_rad`` is not rechecked at all."""
    from holofit.fit.follower import ChunkFitter
    from holofit.fit.rescue import pole_probes, recheck_between

    theory = engine(JANUS)
    f, pos, psi, theta = _single_janus_frame(theory, 22.0, seed=5)
    values = {"x_um": pos[0], "y_um": pos[1], "z_um": pos[2], "alpha": 0.9}
    truth = state_of({**values, "psi_rad": psi, "theta_rad": theta}, JANUS)
    near = state_of({**values, "psi_rad": psi + 1.0, "theta_rad": math.radians(4.0)}, JANUS)
    held = fit_frame_warm(
        FrameProblem(
            f.crop,
            f.corner,
            PX,
            theory,
            JANUS,
            OPTICS,
            ("x_um", "y_um", "z_um", "alpha"),
            settings=FrameFitSettings(mirror=False),
            seed=1,
        ),
        near,
    ).result
    assert _axis_off_deg(held.values, psi, theta) > 15.0
    before, _, _, after = pole_probes(truth, 4, math.radians(16.0))
    later = fit_frame_warm(
        FrameProblem(
            f.crop,
            f.corner,
            PX,
            theory,
            JANUS,
            OPTICS,
            ("x_um", "y_um", "z_um", "alpha"),
            settings=FrameFitSettings(mirror=False),
            seed=1,
        ),
        after,
    ).result
    fitter = ChunkFitter(theory, JANUS, OPTICS, PX, FINAL, FollowSettings())
    res, code, n_eval = recheck_between(fitter, f, held, later, before)
    assert code == 1 and n_eval > 0
    assert _axis_off_deg(res.values, psi, theta) < 2.0
    assert res.rss < held.rss and "neighbours' orientations" in res.message
    excess = (held.rss - res.rss) / res.noise_sd**2
    assert 9.0 < res.extra["delta_chi2"] <= excess + 1e-6 and res.extra["ambiguous"] == 0

    right = fit_frame_warm(
        FrameProblem(f.crop, f.corner, PX, theory, JANUS, OPTICS, FINAL, seed=1), truth
    ).result
    kept, code, n_eval = recheck_between(fitter, f, right, later, before)
    assert code == 0 and kept is right and n_eval > 0
    close = fit_frame_warm(
        FrameProblem(
            f.crop,
            f.corner,
            PX,
            theory,
            JANUS,
            OPTICS,
            ("x_um", "y_um", "z_um", "alpha"),
            settings=FrameFitSettings(mirror=False),
            seed=1,
        ),
        pole_probes(truth, 1, math.radians(10.0))[0],
    ).result
    same, code, n_eval = recheck_between(fitter, f, right, close, before)
    assert code == -1 and same is right and n_eval == 0


def test_a_recheck_replaces_the_row_of_the_frame_it_changed():
    """Three frames of a Janus track near the optical axis (theta 10, 22, 34 deg): the middle
    frame's warm fit held 15+ deg off (theta 4 deg), its neighbours right. Once the third is
    accepted, the recheck refits the middle one from between its neighbours: its row is
    replaced (``follow_recheck`` 1, the truth, its step from the first frame, the holograms of
    both fits counted), and the first frame, within ``recheck_rad`` of the new fit, is not
    rechecked."""
    from holofit.camera import Camera
    from holofit.fit.follow import _Done, _recheck_back, _row
    from holofit.fit.follower import ChunkFitter, ChunkFrame, Followed
    from holofit.simulate.holograms import Exposure, simulate_movie
    from tests.tracking_helpers import BACKGROUND, SHAPE

    theory = engine(JANUS)
    psi = 0.7
    thetas = np.radians([10.0, 22.0, 34.0])
    pos = np.array([[32.3 * PX, 31.6 * PX, 6.0]] * 3) + np.array(
        [[0, 0, 0], [0.04, 0, 0], [0.08, 0.02, 0]]
    )
    movie = simulate_movie(
        JANUS,
        INSTRUMENT,
        pos,
        SHAPE,
        orientations=np.column_stack([[psi] * 3, thetas, [0.0] * 3]),
        alpha=0.9,
        theory=theory,
        seed=3,
        keep_frames=True,
        exposure=Exposure(camera=Camera(background_counts=BACKGROUND)),
    )
    frames = [
        ChunkFrame(k, movie.frames[k] / BACKGROUND, (0, 0), tuple(pos[k]), 0.9, (), 0.01 * k)
        for k in range(3)
    ]

    def fit_from(k, psi_start, theta_start, settings=None, free=FINAL):
        settings = settings or FrameFitSettings()
        start = state_of(
            {
                "x_um": pos[k, 0],
                "y_um": pos[k, 1],
                "z_um": pos[k, 2],
                "alpha": 0.9,
                "psi_rad": psi_start,
                "theta_rad": theta_start,
            },
            JANUS,
        )
        return fit_frame_warm(
            FrameProblem(
                frames[k].crop,
                (0, 0),
                PX,
                theory,
                JANUS,
                OPTICS,
                free,
                settings=settings,
                seed=1,
            ),
            start,
        ).result

    fits = [
        fit_from(0, psi, thetas[0]),
        fit_from(
            1,
            psi + 1.0,
            math.radians(4.0),
            FrameFitSettings(mirror=False),
            ("x_um", "y_um", "z_um", "alpha"),
        ),
        fit_from(2, psi, thetas[2]),
    ]
    assert _axis_off_deg(fits[1].values, psi, thetas[1]) > 15.0
    opts = FollowSettings()
    fitter = ChunkFitter(theory, JANUS, OPTICS, PX, FINAL, opts)
    acc0 = Followed.start(frames[0].frame, fits[0], None, JANUS)
    rows = [_row(frames[k], fits[k], "warm", False, (0.0, 0.0), fits[k].n_eval) for k in range(3)]
    old_rows = [dict(r) for r in rows]
    recent = [
        _Done(frames[0], fits[0], 0, None),
        _Done(frames[1], fits[1], 1, acc0),
        _Done(frames[2], fits[2], 2, acc0),
    ]
    _recheck_back(fitter, recent, rows)
    new = rows[1]
    assert new["follow_recheck"] == 1 and new["follow_source"] == "warm"
    assert _axis_off_deg(new, psi, thetas[1]) < 2.0 and new["chi2"] < old_rows[1]["chi2"]
    assert new["n_eval"] > old_rows[1]["n_eval"]
    assert math.isclose(new["follow_step_axis_rad"], math.radians(12.0), abs_tol=0.05)
    assert rows[0] == old_rows[0] and rows[2] == old_rows[2]


def test_the_orientation_between_two_neighbours():
    """The recheck's start: the fit turned onto the bisector of its neighbours' axes (for a
    head-tail symmetric particle, of the axes as lines), the turn a proper rotation."""
    from holofit.conventions import euler_zyz
    from holofit.fit.rescue import between
    from holofit.holomodel.parameters import State

    def at(psi, theta):
        return State((0.0, 0.0, 5.0), euler_zyz(psi, theta, 0.0), 0.9, ())

    own, a, b = at(0.3, 0.5), at(1.0, 0.2), at(-0.4, 0.4)
    mid = a.rotation[:, 2] + b.rotation[:, 2]
    out = between(own, a, b, head_tail=False)
    assert np.allclose(out.rotation[:, 2], mid / np.linalg.norm(mid))
    assert np.allclose(out.rotation.T @ out.rotation, np.eye(3), atol=1e-12)
    flipped = State(a.position, a.rotation @ np.diag([1.0, -1.0, -1.0]), 0.9, ())  # -u
    assert np.allclose(between(own, flipped, b, head_tail=True).rotation[:, 2], out.rotation[:, 2])
    assert np.allclose(between(own, None, b, head_tail=False).rotation[:, 2], b.rotation[:, 2])


def test_a_chunk_whose_prefit_height_is_far_off_opens_from_another_height(theory):
    """The prefit's heights 8 um above the truth (as a Janus prefit near focus took the twin
    height): the opening library fit from there is ``poor_fit``; tried again from other
    heights it lands on the truth and the rest of the chunk follows warm. Without the other
    heights the opening frame stays poor."""
    track = make_track(theory, n=4, seed=0)
    frames = [
        replace(f, position_um=(f.position_um[0], f.position_um[1], f.position_um[2] + 8.0))
        for f in track.frames
    ]
    plain = follow_chunk(
        frames, chunk_fitter(theory, ROD, OPTICS, PX, FINAL, FollowSettings(reopen_dz_um=())), 1.5
    ).to_dict("records")
    assert plain[0]["status"] == "poor_fit"
    rows = follow_chunk(frames, chunk_fitter(theory, ROD, OPTICS, PX, FINAL), 1.5).to_dict(
        "records"
    )
    assert [r["follow_source"] for r in rows] == ["library"] + ["warm"] * 3
    for k, row in enumerate(rows):
        assert row["status"] == "ok" and _right(track, row, k), (k, row["message"])
    assert "off the prefit's height" in rows[0]["message"]
    assert rows[0]["n_eval"] > plain[0]["n_eval"]  # the other heights' fits counted


def test_a_chunk_no_height_fits_stops_trying_other_heights(theory):
    """Prefit heights at the twin (z -> -z): no height of the ladder reaches the truth, and
    after three frames whose other heights all failed the chunk stops trying (a frame then
    costs what it costs without them)."""
    from holofit.fit.rescue import REOPEN_MAX_FAILURES

    track = make_track(theory, n=REOPEN_MAX_FAILURES + 2, seed=0)
    frames = [
        replace(f, position_um=(f.position_um[0], f.position_um[1], -f.position_um[2]))
        for f in track.frames
    ]
    plain = follow_chunk(
        frames,
        chunk_fitter(
            theory, ROD, OPTICS, PX, FINAL, FollowSettings(reopen_dz_um=(), open_at_best=False)
        ),
        1.5,
    ).to_dict("records")
    rows = follow_chunk(
        frames,
        chunk_fitter(theory, ROD, OPTICS, PX, FINAL, FollowSettings(open_at_best=False)),
        1.5,
    ).to_dict("records")
    assert all(r["status"] != "ok" for r in rows)  # flagged, never ok
    for k, (a, b) in enumerate(zip(plain, rows, strict=True)):
        if k < REOPEN_MAX_FAILURES:
            assert b["n_eval"] > 3 * a["n_eval"]
        else:
            assert b["n_eval"] == a["n_eval"]


def test_the_probes_skip_a_fit_at_its_tracks_level_and_a_rod():
    """A fit near the pole no worse than the median of its track's recent accepted fits is
    not probed (a fit held in a wrong minimum fits worse than its track), and neither is a
    head-tail symmetric particle's unless asked for."""
    from holofit.fit.follower import ChunkFitter, Followed
    from holofit.fit.rescue import probe_near_pole
    from holofit.fit.warm import fit_frame_warm

    theory = engine(JANUS)
    f, pos, psi, theta = _single_janus_frame(theory, 8.0, seed=6)
    truth = state_of(
        {
            "x_um": pos[0],
            "y_um": pos[1],
            "z_um": pos[2],
            "alpha": 0.9,
            "psi_rad": psi,
            "theta_rad": theta,
        },
        JANUS,
    )
    fit = fit_frame_warm(
        FrameProblem(f.crop, f.corner, PX, theory, JANUS, OPTICS, FINAL, seed=1), truth
    ).result
    fitter = ChunkFitter(theory, JANUS, OPTICS, PX, FINAL, FollowSettings())
    above = Followed(0, truth, None, [], [], [], [fit.chi2_red * 1.01] * 3)
    below = Followed(0, truth, None, [], [], [], [fit.chi2_red * 0.99] * 3)
    n = fit.n_eval
    assert probe_near_pole(fitter, f, fit, None, above)[2] == -1 and fit.n_eval == n
    assert probe_near_pole(fitter, f, fit, None, below)[2] == 0 and fit.n_eval > n
    rod_theory = engine()
    track = make_track(rod_theory, n=1, seed=2)
    g = track.frames[0]
    near = state_of(
        {
            "x_um": track.positions[0][0],
            "y_um": track.positions[0][1],
            "z_um": track.positions[0][2],
            "alpha": 0.9,
            "psi_rad": 0.3,
            "theta_rad": 0.1,
        },
        ROD,
    )
    rod_fit = fit_frame_warm(
        FrameProblem(
            g.crop,
            g.corner,
            PX,
            rod_theory,
            ROD,
            OPTICS,
            ("x_um", "y_um", "z_um", "alpha"),
            seed=1,
        ),
        near,
    ).result
    rods = ChunkFitter(rod_theory, ROD, OPTICS, PX, FINAL, FollowSettings())
    assert probe_near_pole(rods, g, rod_fit, None)[2] == -1
    asked = ChunkFitter(
        rod_theory, ROD, OPTICS, PX, FINAL, FollowSettings(pole_probe_symmetric=True)
    )
    assert probe_near_pole(asked, g, rod_fit, None)[2] in (0, 1)
