"""The continuity sweeps (holofit.fit.continuity) on a simulated Brownian trajectory (known
truth) whose fit table has frames knocked into wrong orientations, with a refit oracle that,
like a least-squares fit, finds the true minimum only from a start inside its basin."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from holofit.fit.continuity import (
    ContinuitySettings,
    NeighbourStart,
    followed_suspects,
    repair_by_continuity,
    suspects,
)
from holofit.quality import chi2_bar, flag_bars
from holofit.simulate.brownian import BrownianParameters, simulate_trajectory

NOISE = 0.02
N_PIX = 5000
#: a start closer than this to the truth converges to it (the basin)
BASIN_DEG = 25.0
SINGLES = [17, 60, 61, 140, 222]
RUN = list(range(100, 120))      # a run of twenty bad frames: longer than two max_gap
SUBTLE = [180, 250]              # wrong, with a chi^2 inside the movie's spread


def _axis(theta, psi):
    return np.column_stack([np.sin(theta) * np.cos(psi), np.sin(theta) * np.sin(psi),
                            np.cos(theta)])


def _angles(u):
    return np.arccos(np.clip(u[:, 2], -1, 1)), np.arctan2(u[:, 1], u[:, 0])


@pytest.fixture(scope="module")
def truth() -> pd.DataFrame:
    # the paper's Janus particle: D_r 1.1 /s, 100 frames/s -> ~12 deg between frames
    sim = simulate_trajectory(BrownianParameters(300, 0.01, 0.4, 0.4, 1.1), seed=5)
    t = sim.truth.sort_values("frame").reset_index(drop=True)
    t["theta_rad"], t["psi_rad"] = _angles(_axis(t["theta_rad"], t["psi_rad"]))
    return t


def _row(t: pd.Series, u: np.ndarray, chi2_red: float, start: tuple[float, float]) -> dict:
    theta, psi = _angles(u[None, :])
    return {"frame": int(t["frame"]), "x_um": t["x_um"], "y_um": t["y_um"], "z_um": t["z_um"],
            "theta_rad": float(theta[0]), "psi_rad": float(psi[0]), "ux": u[0], "uy": u[1],
            "uz": u[2], "alpha": 0.9, "chi2": chi2_red * NOISE**2, "chi2_red": chi2_red,
            "noise_sd": NOISE, "n_pixels": N_PIX, "start_theta_rad": start[0],
            "start_psi_rad": start[1], "chi2_runner_up": math.nan, "delta_chi2": math.nan,
            "ambiguous": 0, "runner_up_theta_rad": math.nan, "runner_up_psi_rad": math.nan,
            "runner_up_z_um": math.nan, "status": "ok", "message": ""}


def _far_axis(u: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    while True:
        v = rng.normal(size=3)
        v /= np.linalg.norm(v)
        if np.degrees(np.arccos(np.clip(v @ u, -1, 1))) > 60:
            return v


def _table(truth: pd.DataFrame, seed: int = 1) -> tuple[pd.DataFrame, np.ndarray, np.ndarray]:
    """The fit table, the true axes and each frame's chi^2 at its true minimum."""
    rng = np.random.default_rng(seed)
    u_true = _axis(truth["theta_rad"], truth["psi_rad"])
    chi = 1.0 + 0.01 * rng.normal(size=len(truth))
    rows = [_row(t, u_true[i], chi[i], (math.nan, math.nan)) for i, t in truth.iterrows()]
    for f in SINGLES + RUN + SUBTLE:
        bad = _far_axis(u_true[f], rng)
        rows[f] = _row(truth.iloc[f], bad, chi[f] + (0.004 if f in SUBTLE else 0.6),
                       (math.nan, math.nan))
    return pd.DataFrame(rows), u_true, chi


def _oracle(truth: pd.DataFrame, u_true: np.ndarray, chi: np.ndarray, helps: bool = True):
    """``refit``: the true minimum from a start inside its basin, else a worse fit."""
    calls: list[dict[int, NeighbourStart]] = []

    def refit(sweep: int, starts: dict[int, NeighbourStart]) -> pd.DataFrame:
        calls.append(starts)
        rows = []
        for f, s in starts.items():
            t = truth.iloc[f]
            for c in s.candidates:
                uc = _axis(np.array([c.theta]), np.array([c.psi]))[0]
                near = np.degrees(np.arccos(np.clip(uc @ u_true[f], -1, 1))) < BASIN_DEG
                if near and helps:
                    rows.append(_row(t, u_true[f], chi[f], (c.theta, c.psi)))
                    break
            else:
                rows.append(_row(t, _axis(np.array([s.candidates[0].theta]),
                                          np.array([s.candidates[0].psi]))[0], 5.0,
                                 (s.candidates[0].theta, s.candidates[0].psi)))
        return pd.DataFrame(rows)

    return refit, calls


def _off_deg(table: pd.DataFrame, u_true: np.ndarray) -> np.ndarray:
    u = table[["ux", "uy", "uz"]].to_numpy()
    return np.degrees(np.arccos(np.clip(np.sum(u * u_true, axis=1), -1, 1)))


def test_the_bar_ignores_the_wrong_frames_tail(truth):
    table, _, _ = _table(truth)
    bar = chi2_bar(table, 4.0)
    # the lower half's spread is the noise's 0.01: the bad frames (chi^2 1.6-2.6) cannot
    # inflate it, so the bar sits near 1 + 4 * 0.01
    assert 1.02 < bar < 1.07
    flagged = suspects(table, ContinuitySettings(), head_tail=False)
    assert flagged[SINGLES + RUN].all()


def test_sweeps_bring_every_wrong_frame_back_from_its_neighbours(truth):
    table, u_true, chi = _table(truth)
    before = _off_deg(table, u_true)
    assert (before[SINGLES + RUN + SUBTLE] > 60).all()
    refit, calls = _oracle(truth, u_true, chi)
    out, report = repair_by_continuity(table.copy(), refit, ContinuitySettings(),
                                       head_tail=False, ambiguity_chi2=9.0)
    after = _off_deg(out, u_true)
    assert after.max() < 1e-3, np.flatnonzero(after > 1e-3)
    assert (out["status"] == "ok").all()
    # the run of twenty is eaten from both ends: more than one sweep, each one's frames fewer
    assert report.sweeps >= 2 and report.replaced == len(SINGLES + RUN + SUBTLE)
    assert len(calls[-1]) < len(calls[0])
    fixed = out.set_index("frame").loc[SINGLES + RUN]
    assert fixed["message"].str.contains("trajectory continuity").all()
    # the replaced fit is now the runner-up, far worse than the noise allows: not ambiguous
    assert (fixed["delta_chi2"] > 1000).all() and (fixed["ambiguous"] == 0).all()
    np.testing.assert_allclose(fixed["chi2_runner_up"], table.set_index("frame").loc[
        SINGLES + RUN, "chi2"])
    # the subtle ones, whose chi^2 alone does not give them away, were found by their jump
    assert set(SUBTLE) <= set().union(*calls)
    # good frames are unchanged (a refit from a neighbour finds their own minimum, no better)
    good = sorted(set(range(len(truth))) - set(SINGLES + RUN + SUBTLE))
    pd.testing.assert_frame_equal(out.loc[good], table.loc[good], check_dtype=False)


def test_frames_no_neighbour_helps_become_poor_fit(truth):
    table, u_true, chi = _table(truth)
    refit, calls = _oracle(truth, u_true, chi, helps=False)
    out, report = repair_by_continuity(table.copy(), refit, ContinuitySettings(),
                                       head_tail=False, ambiguity_chi2=9.0)
    assert report.replaced == 0 and report.sweeps == 1 and len(calls) == 1
    st = out.set_index("frame")["status"]
    assert (st.loc[SINGLES + RUN] == "poor_fit").all()
    assert st.drop(SINGLES + RUN + SUBTLE).eq("ok").all()
    assert out.set_index("frame").loc[SINGLES, "message"].str.contains("wrong local").all()


def test_disabled_sweeps_change_nothing(truth):
    table, u_true, chi = _table(truth)
    refit, calls = _oracle(truth, u_true, chi)
    out, report = repair_by_continuity(table.copy(), refit,
                                       ContinuitySettings(enabled=False), head_tail=False,
                                       ambiguity_chi2=9.0)
    assert not calls and report.sweeps == 0
    pd.testing.assert_frame_equal(out, table, check_dtype=False)


def test_options_are_checked():
    with pytest.raises(ValueError, match="max_gap"):
        ContinuitySettings(max_gap=0)
    with pytest.raises(ValueError, match="chi2_sigmas"):
        ContinuitySettings(chi2_sigmas=0)


def test_a_refit_into_the_same_minimum_replaces_nothing(truth):
    """A refit that finds a frame's own minimum again differs by solver precision: no row is
    replaced, so no neighbour is set off, and the sweeps stop."""
    table, u_true, chi = _table(truth)
    refit, _ = _oracle(truth, u_true, chi - 1e-9)  # 1e-9 in chi^2 per pixel: << noise
    out, report = repair_by_continuity(table.copy(), refit, ContinuitySettings(),
                                       head_tail=False, ambiguity_chi2=9.0)
    good = sorted(set(range(len(truth))) - set(SINGLES + RUN + SUBTLE))
    pd.testing.assert_frame_equal(out.loc[good], table.loc[good], check_dtype=False)
    assert report.replaced == len(SINGLES + RUN + SUBTLE)


# -- the flag bar: a frame in the right minimum is flagged with probability <= p ------------

def _right_minimum_chi2(rng: np.random.Generator, n_frames: int, n_pix: int,
                        noise_error: float) -> np.ndarray:
    """Reduced chi^2 of frames in their right minimum, as a fit computes it: the residual
    sum of squares of ``n_pix`` pixels of pure noise (chi^2 with n_pix degrees of freedom)
    over each frame's *estimated* noise^2, the estimate off by a relative normal error of sd
    ``noise_error``; 0.98: the estimator's bias, common to the movie."""
    rss = rng.chisquare(n_pix, n_frames) / n_pix
    return 0.98 * rss / (1.0 + noise_error * rng.normal(size=n_frames)) ** 2


def _ok_table(chi2_red: np.ndarray, n_pix: int) -> pd.DataFrame:
    return pd.DataFrame({"status": "ok", "chi2_red": chi2_red, "n_pixels": n_pix})


@pytest.mark.parametrize(("n_frames", "trials", "noise_error"),
                         [(30, 2000, 0.01), (300, 500, 0.01), (300, 500, 0.0)])
def test_right_minimum_frames_are_flagged_with_the_probability_asked(n_frames, trials,
                                                                    noise_error):
    """Monte Carlo with known truth: every frame is in its right minimum, so each flag is a
    false one; their share must stay at or under the probability asked (here 1e-3, to count
    enough). The old bar (median + 4 lower-half spreads) flagged 3e-3 of a 30-frame movie's
    good frames: ~1 in every 10 such movies lost a good frame, a 2000-frame movie a dozen."""
    p = 1e-3
    rng = np.random.default_rng(n_frames + int(1000 * noise_error))
    flagged = total = 0
    for _ in range(trials):
        chi = _right_minimum_chi2(rng, n_frames, 19600, noise_error)
        flagged += int((chi > flag_bars(_ok_table(chi, 19600), p).bars).sum())
        total += n_frames
    # a binomial count at rate p exceeds p * total + 3 sd with probability ~1e-3
    assert flagged <= p * total + 3 * math.sqrt(p * total), (flagged, total)


def test_the_flag_bar_follows_each_frames_pixel_count():
    """Fewer pixels, a wider chi^2: with the excess measured, the bar of a frame with 1/16 of
    the pixels is the chi^2 distribution's own at least (exactly, when no excess is seen)."""
    rng = np.random.default_rng(3)
    nu = np.full(200, 19600)
    nu[:5] = 1225
    chi = rng.chisquare(nu) / nu
    bars = flag_bars(pd.DataFrame({"status": "ok", "chi2_red": chi, "n_pixels": nu}), 1e-4)
    from scipy import stats
    med = np.median(chi)
    assert bars.bars[0] >= med * stats.chi2.isf(1e-4, 1225) / 1225 - 1e-12
    assert bars.bars[0] > bars.bars[10] > med * stats.chi2.isf(1e-4, 19600) / 19600 - 1e-12
    assert bars.typical == pytest.approx(bars.bars[10])


def test_30_frame_movies_no_longer_lose_good_frames():
    """The reported case, a 30-frame rod movie (19600 pixels a frame, reduced chi^2 spread
    ~1.5 %) whose frame 26, in its right minimum, was flagged at 1.049 against the old bar
    1.047: of 200 such simulated movies (every frame in its right minimum) the old bar flags
    a good frame in about one in twenty; the flag bar in none."""
    old = new = 0
    for seed in range(200):
        rng = np.random.default_rng(seed)
        table = _ok_table(_right_minimum_chi2(rng, 30, 19600, 0.005), 19600)
        chi = table["chi2_red"].to_numpy()
        old += bool((chi > chi2_bar(table, 4.0)).any())
        new += bool((chi > flag_bars(table, 1e-4).bars).any())
    assert old >= 5 and new == 0, (old, new)


def test_a_frame_is_demoted_only_for_an_improbable_chi2(truth):
    """A movie where the old bar flagged a good frame (seed 18: its largest reduced chi^2,
    1.027, over the old bar 1.023). A refit from a neighbour finds each suspect's own minimum
    again (no better): the good frame stays ok; a frame in a wrong minimum (chi^2 1.5) is
    flagged, and its message says with which probability a right one would be."""
    rng = np.random.default_rng(18)
    chi = _right_minimum_chi2(rng, 30, 19600, 0.005)
    u = _axis(truth["theta_rad"][:30].to_numpy(), truth["psi_rad"][:30].to_numpy())
    table = pd.DataFrame([_row(truth.iloc[i], u[i], float(c), (math.nan, math.nan))
                          for i, c in enumerate(chi)])
    table["n_pixels"] = 19600
    top = int(np.argmax(chi))
    assert chi2_bar(table, 4.0) < chi[top]  # what flagged it before
    wrong = (top + 9) % 30
    table.loc[wrong, ["chi2_red", "chi2"]] = 1.5, 1.5 * NOISE**2

    def same_minimum(sweep, starts):
        return table.loc[table["frame"].isin(list(starts))].copy()

    out, report = repair_by_continuity(table.copy(), same_minimum, ContinuitySettings(),
                                       head_tail=True, ambiguity_chi2=9.0)
    st = out["status"].to_numpy()
    assert st[top] == "ok"
    assert st[wrong] == "poor_fit" and report.flagged == 1
    assert chi[top] < report.flag_bar < 1.5
    assert "probability 0.0001" in out["message"].iat[wrong]


def test_the_flag_probability_is_the_users():
    with pytest.raises(ValueError, match="flag_probability"):
        ContinuitySettings(flag_probability=0.0)
    rng = np.random.default_rng(4)
    table = _ok_table(_right_minimum_chi2(rng, 100, 19600, 0.01), 19600)
    assert flag_bars(table, 1e-2).typical < flag_bars(table, 1e-4).typical


# -- tracked tables: the tracker has checked each frame; the sweeps refit only its suspects --

def _tracked(table: pd.DataFrame) -> pd.DataFrame:
    """``table`` as the tracking final pass writes it: frame 0 a library fit, the rest warm."""
    t = table.copy()
    t["follow_source"] = ["library"] + ["warm"] * (len(t) - 1)
    t["follow_jump"] = 0
    return t


def _clean(truth: pd.DataFrame, seed: int = 1) -> tuple[pd.DataFrame, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    u_true = _axis(truth["theta_rad"], truth["psi_rad"])
    chi = 1.0 + 0.01 * rng.normal(size=len(truth))
    rows = [_row(t, u_true[i], chi[i], (math.nan, math.nan)) for i, t in truth.iterrows()]
    return pd.DataFrame(rows), u_true, chi


def test_a_clean_tracked_table_is_not_refitted_where_an_untracked_one_is(truth):
    """Every frame in its right minimum: on the tracked table (each warm frame already under
    the bar with a smooth step) the sweeps refit nothing; the untracked rule (``--no-tracking``)
    still refits the frames whose step is above the median, as before."""
    table, u_true, chi = _clean(truth)
    refit, calls = _oracle(truth, u_true, chi)
    _, report = repair_by_continuity(_tracked(table), refit, ContinuitySettings(),
                                       head_tail=False, ambiguity_chi2=9.0)
    assert not calls and report.refitted == 0 and report.replaced == 0
    assert not followed_suspects(_tracked(table), ContinuitySettings(), head_tail=False).any()
    refit, calls = _oracle(truth, u_true, chi)
    _, untracked = repair_by_continuity(table.copy(), refit, ContinuitySettings(),
                                        head_tail=False, ambiguity_chi2=9.0)
    assert untracked.refitted > len(truth) // 2 and untracked.replaced == 0


def test_the_trackers_suspects_are_still_refitted_and_repaired(truth):
    """On a tracked table: a re-acquired frame left in a wrong minimum (chi^2 inside the
    movie's spread), an ambiguous one, a frame flagged ``follow_jump`` (and its neighbours), a
    warm frame 90 deg off its neighbours (a seam of the chunks) and a poor_fit one are refitted;
    the wrong ones come back to the truth; no other frame is refitted."""
    table, u_true, chi = _clean(truth)
    t = _tracked(table)
    rng = np.random.default_rng(3)
    reacq, ambig, jump, seam, poor = 40, 90, 150, 200, 260
    for f in (reacq, seam, poor):
        bad = _far_axis(u_true[f], rng)
        if f == seam:  # 90 deg from the truth, far beyond five median steps
            v = np.cross(u_true[f], rng.normal(size=3))
            bad = v / np.linalg.norm(v)
        new = _row(truth.iloc[f], bad, chi[f] + (0.6 if f == poor else 0.004),
                   (math.nan, math.nan))
        for col, value in new.items():
            t.at[f, col] = value
    t.at[reacq, "follow_source"] = "reacquired"
    t.at[poor, "status"] = "poor_fit"
    t.at[ambig, "ambiguous"] = 1
    t.at[jump, "follow_source"], t.at[jump, "follow_jump"] = "reacquired", 1
    refit, calls = _oracle(truth, u_true, chi)
    out, report = repair_by_continuity(t, refit, ContinuitySettings(), head_tail=False,
                                       ambiguity_chi2=9.0)
    refitted = set().union(*calls)
    assert {reacq, ambig, jump, jump - 1, jump + 1, seam, poor} <= refitted
    # the neighbours of the wrong ok frames see their jump too; nothing else
    assert refitted <= {reacq - 1, reacq, reacq + 1, ambig, jump - 1, jump, jump + 1,
                        seam - 1, seam, seam + 1, poor}
    assert report.replaced == 3
    assert _off_deg(out, u_true).max() < 1e-3 and (out["status"] == "ok").all()


def test_the_small_sample_bar_rarely_flags_a_right_frame_and_catches_one_clearly_off():
    """Right-minimum frames of a short movie: reduced chi^2 ``m (1 + r)``, ``r`` normal with
    the chi^2 distribution's variance for 19600 pixels plus an excess of 0 or 1 %: a new
    right frame lies above the bar built from 1-9 such frames in at most 0.3 % of movies,
    a frame 15 % off the data in at least 99 %, and from 10 rows on the bar is chi2_bar's."""
    from holofit.quality import small_sample_bar

    rng = np.random.default_rng(3)
    nu = 19600
    for excess in (0.0, 0.01):
        sd = math.sqrt(2.0 / nu + excess**2)
        for n in (1, 2, 3, 5, 8, 9):
            above = off = 0
            for _ in range(2000):
                chi = 1.03 * (1.0 + rng.normal(0.0, sd, n + 1))
                tab = pd.DataFrame({"status": "ok", "chi2_red": chi[:n], "n_pixels": nu})
                bar = small_sample_bar(tab, 4.0)
                above += chi[n] > bar
                off += 1.03 * 1.15 > bar
            assert above <= 6, (excess, n, above)
            assert off >= 1980
    tab = pd.DataFrame({"status": "ok", "chi2_red": 1.0 + rng.normal(0, 0.01, 12),
                        "n_pixels": nu})
    assert small_sample_bar(tab, 4.0) == chi2_bar(tab, 4.0)
    assert math.isnan(small_sample_bar(tab.assign(status="failed"), 4.0))
