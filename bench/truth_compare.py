"""A fit table against the simulation's truth: the numbers the validation scripts report.

Shared by ``bench/validate_fit.py`` and ``bench/replicate.py`` (not part of the package: it
needs the simulation's truth, which a user's movie does not have).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

#: an axis further than this from the truth is on the wrong branch, deg
WRONG_BRANCH_DEG = 10.0
#: the Janus azimuth is scored where the axis is this far from the optical axis (|sin theta|)
PSI_SIN_THETA = 0.3


def axis_from_angles(theta: np.ndarray, psi: np.ndarray) -> np.ndarray:
    """Unit axes (n, 3) from polar angle ``theta`` and azimuth ``psi`` (rad)."""
    return np.column_stack([np.sin(theta) * np.cos(psi), np.sin(theta) * np.sin(psi),
                            np.cos(theta)])


def compare_with_truth(fit: pd.DataFrame, truth: pd.DataFrame, *,
                       head_tail_symmetric: bool) -> dict[str, object]:
    """Score a final-pass fit table against the true trajectory.

    Parameters
    ----------
    fit : DataFrame
        The fit table (``fit.csv``), indexed by frame.
    truth : DataFrame
        The simulation's truth, indexed by frame (``x_um``, ``y_um``, ``z_um``, ``theta_rad``,
        ``psi_rad``).
    head_tail_symmetric : bool
        Whether u and -u are one orientation (a rod), so the axis error is folded.

    Returns
    -------
    dict
        ``statuses``, ``ok_fraction``; over the ``ok`` frames: ``rms_nm`` (x, y, z, nm),
        ``xy_rms_nm``, ``axis_rms_deg`` (frames on the right branch), ``wrong_branch_frames``
        (axis more than :data:`WRONG_BRANCH_DEG` off), ``wrong_branch_unflagged`` (of those,
        not flagged ``ambiguous``), ``ambiguous_frames``, and ``psi_rms_deg`` where
        ``|sin theta| > PSI_SIN_THETA`` over every ``ok`` frame (the azimuth of an axis near
        the optical axis is undefined), with ``psi_frames`` the frames it is taken over;
        ``axis_sigma_rms_deg``, the rms of the axis error the fits report (``d_theta_rad`` and
        ``sin theta d_psi_rad`` in quadrature, the right-branch frames), and
        ``axis_chi2_mean``, the mean of (axis error / reported error)^2 there: 1 where the
        axis is as good as the noise allows and its error bars hold, more where a model error
        adds to the noise.
    """
    ok = (fit["status"] == "ok").to_numpy()
    f = fit[ok]
    tr = truth.loc[f.index]
    rms = {k: 1e3 * float(np.sqrt(np.mean((f[k] - tr[k]) ** 2))) for k in
           ("x_um", "y_um", "z_um")}
    u_fit = f[["ux", "uy", "uz"]].to_numpy()
    u_true = axis_from_angles(tr["theta_rad"].to_numpy(), tr["psi_rad"].to_numpy())
    dot = np.sum(u_fit * u_true, axis=1)
    if head_tail_symmetric:
        dot = np.abs(dot)
    ang = np.degrees(np.arccos(np.clip(dot, -1, 1)))
    wrong = ang > WRONG_BRANCH_DEG
    amb = f["ambiguous"].fillna(0).to_numpy().astype(bool)
    sel = np.abs(np.sin(tr["theta_rad"].to_numpy())) > PSI_SIN_THETA
    dpsi = (f["psi_rad"].to_numpy() - tr["psi_rad"].to_numpy() + np.pi) % (2 * np.pi) - np.pi
    if head_tail_symmetric:  # psi and psi + pi are one azimuth of a symmetric axis
        dpsi = (dpsi + np.pi / 2) % np.pi - np.pi / 2
    good = sel  # the azimuth of the mirrored Janus orientation (pi - theta) is the same
    # the reported axis error: two perpendicular components, so E[angle^2] = their sum
    sigma = np.degrees(np.hypot(f["d_theta_rad"].to_numpy(),
                                np.sin(f["theta_rad"].to_numpy()) * f["d_psi_rad"].to_numpy()))
    right = ~wrong & np.isfinite(sigma) & (sigma > 0)
    return {
        "statuses": fit["status"].value_counts().to_dict(),
        "ok_fraction": float(ok.mean()),
        "rms_nm": rms,
        "xy_rms_nm": float(np.sqrt((rms["x_um"] ** 2 + rms["y_um"] ** 2) / 2)),
        "axis_rms_deg": float(np.sqrt(np.mean(ang[~wrong] ** 2))) if (~wrong).any() else None,
        "wrong_branch_frames": int(wrong.sum()),
        "wrong_branch_unflagged": int((wrong & ~amb).sum()),
        "ambiguous_frames": int(amb.sum()),
        "psi_rms_deg": float(np.degrees(np.sqrt(np.mean(dpsi[good] ** 2))))
        if good.any() else None,
        "psi_frames": int(good.sum()),
        "axis_sigma_rms_deg": float(np.sqrt(np.mean(sigma[right] ** 2))) if right.any() else None,
        "axis_chi2_mean": float(np.mean((ang[right] / sigma[right]) ** 2)) if right.any() else None,
    }
