"""Compiled inner loops of the Lorenz-Mie field (numba).

Kept apart from :mod:`holofit.scattering.mie` so that the physics there reads as plain array
code. Everything here transcribes Bohren & Huffman eqs. (4.40)-(4.50): the field scattered by a
sphere illuminated by an x-polarised plane wave travelling along +z, in the sphere's own frame
("B&H frame"), with exact spherical Hankel functions ``h_n = h_n^(1)``:

    E_r   =  cos(phi) sin(th) / (kr) * sum_n c1_n n(n+1) pi_n h_n
    E_th  =  cos(phi) * sum_n (c1_n tau_n xi'_n/(kr) + c2_n pi_n h_n)
    E_phi = -sin(phi) * sum_n (c1_n pi_n xi'_n/(kr) + c2_n tau_n h_n)

with ``c1_n = i E_n a_n``, ``c2_n = -E_n b_n``, ``E_n = i^n (2n+1)/(n(n+1))`` and
``xi'_n(x)/x = h_{n-1}(x) - n h_n(x)/x``. The far-field form replaces ``h_n`` by
``(-i)^(n+1) exp(ikr)/(kr)`` and ``xi'_n/(kr)`` by ``(-i)^n exp(ikr)/(kr)`` and drops ``E_r``.

The loops run over blocks of points with the series order outside and the points inside, in
real arithmetic, so that LLVM vectorises the point loop (several times faster than a
point-outer complex loop; docs: validation, "Lorenz-Mie and the lens").
"""

from __future__ import annotations

import numba
import numpy as np

#: fast-math flags that allow FMA contraction and reassociation but keep inf/nan semantics
FASTMATH = {"contract", "reassoc", "nsz", "arcp"}
BLOCK = 64


@numba.njit(cache=True, fastmath=FASTMATH, nogil=True)
def _series_block(pts, nb, k, c1r, c1i, c2r, c2i, far, out):  # pragma: no cover - compiled
    """Field at ``pts[:nb]`` (B&H frame, um) into ``out[:nb]`` (B&H Cartesian)."""
    nmax = c1r.shape[0]
    B = pts.shape[0]
    hr = np.empty(B)
    hi = np.empty(B)
    hpr = np.empty(B)
    hpi = np.empty(B)
    pin = np.empty(B)
    pip = np.empty(B)
    mu = np.empty(B)
    inv = np.empty(B)
    err = np.zeros(B)
    eri = np.zeros(B)
    etr = np.zeros(B)
    eti = np.zeros(B)
    epr = np.zeros(B)
    epi = np.zeros(B)
    for q in range(nb):
        r = np.sqrt(pts[q, 0] ** 2 + pts[q, 1] ** 2 + pts[q, 2] ** 2)
        kr = k * r
        mu[q] = pts[q, 2] / r
        iv = 1.0 / kr
        inv[q] = iv
        c = np.cos(kr)
        s = np.sin(kr)
        if far:
            # h_1 -> -exp(ix)/x ; the "previous" slot is unused in far mode
            hr[q] = -c * iv
            hi[q] = -s * iv
            hpr[q] = 0.0
            hpi[q] = 0.0
        else:
            # h_0 = -i exp(ix)/x ; h_1 = -exp(ix)(x + i)/x^2
            hpr[q] = s * iv
            hpi[q] = -c * iv
            hr[q] = -(c * kr - s) * iv * iv
            hi[q] = -(s * kr + c) * iv * iv
        pip[q] = 0.0
        pin[q] = 1.0
        err[q] = 0.0
        eri[q] = 0.0
        etr[q] = 0.0
        eti[q] = 0.0
        epr[q] = 0.0
        epi[q] = 0.0
    for n in range(1, nmax + 1):
        a_r = c1r[n - 1]
        a_i = c1i[n - 1]
        b_r = c2r[n - 1]
        b_i = c2i[n - 1]
        nn1 = n * (n + 1.0)
        f2 = 2.0 * n + 1.0
        fn = float(n)
        fn1 = n + 1.0
        invn = 1.0 / n
        radial = 0.0 if far else 1.0
        for q in range(nb):
            p = pin[q]
            pp = pip[q]
            m = mu[q]
            iv = inv[q]
            t = fn * m * p - fn1 * pp
            h_r = hr[q]
            h_i = hi[q]
            hp_r = hpr[q]
            hp_i = hpi[q]
            if far:
                d_r = -h_i  # xi'_n/(kr) = i h_n in the far field
                d_i = h_r
            else:
                d_r = hp_r - fn * h_r * iv
                d_i = hp_i - fn * h_i * iv
            u_r = a_r * d_r - a_i * d_i
            u_i = a_r * d_i + a_i * d_r
            v_r = b_r * h_r - b_i * h_i
            v_i = b_r * h_i + b_i * h_r
            w_r = a_r * h_r - a_i * h_i
            w_i = a_r * h_i + a_i * h_r
            err[q] += radial * nn1 * p * w_r
            eri[q] += radial * nn1 * p * w_i
            etr[q] += t * u_r + p * v_r
            eti[q] += t * u_i + p * v_i
            epr[q] += p * u_r + t * v_r
            epi[q] += p * u_i + t * v_i
            if far:
                hr[q] = h_i  # h_{n+1} = -i h_n
                hi[q] = -h_r
            else:
                hr[q] = f2 * iv * h_r - hp_r
                hi[q] = f2 * iv * h_i - hp_i
                hpr[q] = h_r
                hpi[q] = h_i
            pip[q] = p
            pin[q] = (f2 * m * p - fn1 * pp) * invn
    for q in range(nb):
        x = pts[q, 0]
        y = pts[q, 1]
        rxy = np.sqrt(x * x + y * y)
        r = np.sqrt(rxy * rxy + pts[q, 2] ** 2)
        st = rxy / r
        ct = mu[q]
        if rxy > 0.0:
            cp = x / rxy
            sp = y / rxy
        else:
            cp = 1.0
            sp = 0.0
        er = (err[q] + 1j * eri[q]) * (cp * st * inv[q])
        et = (etr[q] + 1j * eti[q]) * cp
        ep = -(epr[q] + 1j * epi[q]) * sp
        out[q, 0] = er * st * cp + et * ct * cp - ep * sp
        out[q, 1] = er * st * sp + et * ct * sp + ep * cp
        out[q, 2] = er * ct - et * st


@numba.njit(cache=True, fastmath=FASTMATH, nogil=True)
def field_at_points(pts_bh, k, c1r, c1i, c2r, c2i, far, out):  # pragma: no cover - compiled
    """Field at ``pts_bh`` (N, 3), B&H frame, into ``out`` (N, 3) complex, B&H frame."""
    n = pts_bh.shape[0]
    buf = np.empty((BLOCK, 3))
    res = np.empty((BLOCK, 3), dtype=np.complex128)
    for start in range(0, n, BLOCK):
        nb = min(BLOCK, n - start)
        for q in range(nb):
            buf[q, 0] = pts_bh[start + q, 0]
            buf[q, 1] = pts_bh[start + q, 1]
            buf[q, 2] = pts_bh[start + q, 2]
        _series_block(buf, nb, k, c1r, c1i, c2r, c2i, far, res)
        for q in range(nb):
            out[start + q, 0] = res[q, 0]
            out[start + q, 1] = res[q, 1]
            out[start + q, 2] = res[q, 2]


@numba.njit(cache=True, fastmath=FASTMATH, nogil=True)
def field_on_pixels(
    xs, ys, position, frame, k, coefs, far, ex, ey
):  # pragma: no cover - compiled
    """Lab transverse field at pixel centres ``(xs[q], ys[q])`` (um), incident phase included.

    ``position`` is the particle's ``(x, y, z)``, um; ``frame`` maps lab vectors to the B&H
    frame; ``coefs`` the series' ``(c1r, c1i, c2r, c2i)``; ``ex, ey`` have the length of
    ``xs``.
    """
    xp, yp, zp = position
    c1r, c1i, c2r, c2i = coefs
    n = xs.shape[0]
    buf = np.empty((BLOCK, 3))
    res = np.empty((BLOCK, 3), dtype=np.complex128)
    phase = np.cos(k * zp) - 1j * np.sin(k * zp)
    for start in range(0, n, BLOCK):
        nb = min(BLOCK, n - start)
        for q in range(nb):
            lx = xs[start + q] - xp
            ly = ys[start + q] - yp
            lz = -zp
            for c in range(3):
                buf[q, c] = frame[c, 0] * lx + frame[c, 1] * ly + frame[c, 2] * lz
        _series_block(buf, nb, k, c1r, c1i, c2r, c2i, far, res)
        for q in range(nb):
            # E_lab = frame.T @ E_bh
            vx = frame[0, 0] * res[q, 0] + frame[1, 0] * res[q, 1] + frame[2, 0] * res[q, 2]
            vy = frame[0, 1] * res[q, 0] + frame[1, 1] * res[q, 1] + frame[2, 1] * res[q, 2]
            ex[start + q] = vx * phase
            ey[start + q] = vy * phase


@numba.njit(cache=True, nogil=True)
def angular_pi_tau(mu, nmax):  # pragma: no cover - compiled
    """Angular functions ``pi_n(mu)``, ``tau_n(mu)`` for n = 1..nmax, shapes (nmax, len(mu))."""
    npts = mu.shape[0]
    pi = np.zeros((nmax, npts))
    tau = np.zeros((nmax, npts))
    for p in range(npts):
        m = mu[p]
        pi_prev = 0.0
        pi_n = 1.0
        for n in range(1, nmax + 1):
            pi[n - 1, p] = pi_n
            tau[n - 1, p] = n * m * pi_n - (n + 1) * pi_prev
            pi_next = ((2 * n + 1) * m * pi_n - (n + 1) * pi_prev) / n
            pi_prev = pi_n
            pi_n = pi_next
    return pi, tau
