"""Compiled (numba) core of RPnP, steps 2-5 of :func:`eaglemission.estimators.rpnp.rpnp`.

The same arithmetic as the numpy reference path ``_rpnp_numpy`` in rpnp.py (tests compare the
two), without numpy's per-call overhead, which dominates at n = 4. Compiled on first use and
cached on disk (``cache=True``). Also the Levenberg-Marquardt loop of
:func:`~eaglemission.estimators.pnp_refine.refine_pose` (``refine_pose_core``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

_IMAG_TOL = 1e-3


@njit(cache=True)
def _frame_from_axis(x0: float, x1: float, x2: float) -> np.ndarray:
    if abs(x1) < abs(x2):
        z0, z1, z2 = -x2, 0.0, x0
        nz = math.sqrt(z0 * z0 + z2 * z2)
        z0, z2 = z0 / nz, z2 / nz
        y0, y1, y2 = z1 * x2 - z2 * x1, z2 * x0 - z0 * x2, z0 * x1 - z1 * x0
    else:
        y0, y1, y2 = -x1, x0, 0.0
        ny = math.sqrt(y0 * y0 + y1 * y1)
        y0, y1 = y0 / ny, y1 / ny
        z0, z1, z2 = x1 * y2 - x2 * y1, x2 * y0 - x0 * y2, x0 * y1 - x1 * y0
    ny = math.sqrt(y0 * y0 + y1 * y1 + y2 * y2)
    nz = math.sqrt(z0 * z0 + z1 * z1 + z2 * z2)
    M = np.empty((3, 3))
    M[0, 0], M[1, 0], M[2, 0] = x0, x1, x2
    M[0, 1], M[1, 1], M[2, 1] = y0 / ny, y1 / ny, y2 / ny
    M[0, 2], M[1, 2], M[2, 2] = z0 / nz, z1 / nz, z2 / nz
    return M


@njit(cache=True)
def _det3(m: np.ndarray) -> float:
    d: float = (m[0, 0] * (m[1, 1] * m[2, 2] - m[1, 2] * m[2, 1])
                - m[0, 1] * (m[1, 0] * m[2, 2] - m[1, 2] * m[2, 0])
                + m[0, 2] * (m[1, 0] * m[2, 1] - m[1, 1] * m[2, 0]))
    return d


@njit(cache=True)
def rpnp_core(  # noqa: C901
    XXw: np.ndarray, xx: np.ndarray, i1: int, i2: int
) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
    """Candidates of RPnP for the pair (i1, i2).

    Returns (status, Rs (m,3,3), ts (m,3), errs (m,)): status 0 ok, 1 coincident pair,
    2 non-finite polynomial, 3 no local minimum, 4 no finite linear solution. ``errs`` is the
    mean reprojection error (inf when a point falls behind the camera)."""
    n = XXw.shape[0]
    empty_R = np.zeros((0, 3, 3))
    empty_t = np.zeros((0, 3))
    empty_e = np.zeros(0)
    xv = np.empty((n, 3))
    for j in range(n):
        a, b = xx[j, 0], xx[j, 1]
        nr = math.sqrt(a * a + b * b + 1.0)
        xv[j, 0], xv[j, 1], xv[j, 2] = a / nr, b / nr, 1.0 / nr

    # Step 1 (frame of the pair).
    d0 = XXw[i2, 0] - XXw[i1, 0]
    d1 = XXw[i2, 1] - XXw[i1, 1]
    d2 = XXw[i2, 2] - XXw[i1, 2]
    D1 = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
    cx = 0.0
    cy = 0.0
    cz = 0.0
    for j in range(n):
        cx += XXw[j, 0]
        cy += XXw[j, 1]
        cz += XXw[j, 2]
    cx /= n
    cy /= n
    cz /= n
    scale2 = 0.0
    for j in range(n):
        e = (XXw[j, 0] - cx) ** 2 + (XXw[j, 1] - cy) ** 2 + (XXw[j, 2] - cz) ** 2
        if e > scale2:
            scale2 = e
    if not D1 > 1e-12 * max(math.sqrt(scale2), 1e-300):
        return 1, empty_R, empty_t, empty_e
    Ro = _frame_from_axis(d0 / D1, d1 / D1, d2 / D1)
    p00 = (XXw[i1, 0] + XXw[i2, 0]) / 2.0
    p01 = (XXw[i1, 1] + XXw[i2, 1]) / 2.0
    p02 = (XXw[i1, 2] + XXw[i2, 2]) / 2.0
    XX = np.empty((n, 3))
    for j in range(n):
        q0, q1, q2 = XXw[j, 0] - p00, XXw[j, 1] - p01, XXw[j, 2] - p02
        for k in range(3):
            XX[j, k] = q0 * Ro[0, k] + q1 * Ro[1, k] + q2 * Ro[2, k]

    # Step 2: quartics and the degree-7 polynomial.
    v1 = xv[i1]
    v2 = xv[i2]
    cg1 = v1[0] * v2[0] + v1[1] * v2[1] + v1[2] * v2[2]
    sg1_2 = 1.0 - cg1 * cg1
    P = np.zeros(8)
    for j in range(n):
        if j == i1 or j == i2:
            continue
        cg2 = xv[j, 0] * v1[0] + xv[j, 1] * v1[1] + xv[j, 2] * v1[2]
        cg3 = xv[j, 0] * v2[0] + xv[j, 1] * v2[1] + xv[j, 2] * v2[2]
        D2s = (XX[j, 0] - XX[i1, 0]) ** 2 + (XX[j, 1] - XX[i1, 1]) ** 2 + (XX[j, 2] - XX[i1, 2]) ** 2
        D3s = (XX[j, 0] - XX[i2, 0]) ** 2 + (XX[j, 1] - XX[i2, 1]) ** 2 + (XX[j, 2] - XX[i2, 2]) ** 2
        A1 = D2s / (D1 * D1)
        A2 = A1 * sg1_2 - (1.0 - cg2 * cg2)
        A3 = cg2 * cg3 - cg1
        A4 = cg1 * cg3 - cg2
        A6 = (D3s - D1 * D1 - D2s) / (2.0 * D1 * D1)
        A7 = 1.0 - cg1 * cg1 - cg2 * cg2 + cg1 * cg2 * cg3 + A6 * sg1_2
        a = A6 * A6 - A1 * cg3 * cg3
        b = 2.0 * (A3 * A6 - A1 * A4 * cg3)
        c = A3 * A3 + 2.0 * A6 * A7 - A1 * A4 * A4 - A2 * cg3 * cg3
        d = 2.0 * (A3 * A7 - A2 * A4 * cg3)
        e = A7 * A7 - A2 * A4 * A4
        P[0] += 4 * a * a
        P[1] += 7 * a * b
        P[2] += 6 * a * c + 3 * b * b
        P[3] += 5 * a * d + 5 * b * c
        P[4] += 4 * a * e + 4 * b * d + 2 * c * c
        P[5] += 3 * b * e + 3 * c * d
        P[6] += 2 * c * e + d * d
        P[7] += d * e
    for k in range(8):
        if not math.isfinite(P[k]):
            return 2, empty_R, empty_t, empty_e

    # Step 3: real roots that are local minima.
    lead = 0
    while lead < 8 and P[lead] == 0.0:
        lead += 1
    deg = 7 - lead
    if deg < 1:
        return 3, empty_R, empty_t, empty_e
    comp = np.zeros((deg, deg), dtype=np.complex128)
    for k in range(deg):
        comp[0, k] = -P[lead + 1 + k] / P[lead]
    for k in range(1, deg):
        comp[k, k - 1] = 1.0
    roots = np.linalg.eigvals(comp)
    maxreal = 0.0
    for r in roots:
        if abs(r.real) > maxreal:
            maxreal = abs(r.real)
    t2s = np.empty(deg)
    m = 0
    for r in roots:
        if (maxreal > 0 and abs(r.imag) / maxreal <= _IMAG_TOL) or (maxreal == 0 and abs(r.imag) <= _IMAG_TOL):
            t = r.real
            # Second derivative sign: derivative of P at t.
            dp = 0.0
            for k in range(deg):
                dp = dp * t + (deg - k) * P[lead + k]
            if dp > 0:
                t2s[m] = t
                m += 1
    if m == 0:
        return 3, empty_R, empty_t, empty_e

    # Step 4: per root, the axis and the 2n x 6 linear system.
    Rs = np.empty((m, 3, 3))
    ts = np.empty((m, 3))
    errs = np.full(m, np.inf)
    A = np.empty((n, 3))
    B = np.empty((n, 3))
    C = np.empty((n, 3))
    Xc = np.empty((n, 3))
    count = 0
    for r in range(m):
        dd = cg1 + t2s[r]
        a0, a1, a2 = v2[0] * dd - v1[0], v2[1] * dd - v1[1], v2[2] * dd - v1[2]
        na = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
        if not na > 1e-12:
            continue
        Mx = _frame_from_axis(a0 / na, a1 / na, a2 / na)
        DTD = np.zeros((6, 6))
        row = np.zeros(6)
        for j in range(n):
            xi, yi, zi = XX[j, 0], XX[j, 1], XX[j, 2]
            for k in range(3):
                A[j, k] = Mx[k, 1] * yi + Mx[k, 2] * zi
                B[j, k] = Mx[k, 2] * yi - Mx[k, 1] * zi
                C[j, k] = Mx[k, 0] * xi
            for axis in range(2):
                uu = xx[j, axis]
                row[0] = A[j, axis] - uu * A[j, 2]
                row[1] = B[j, axis] - uu * B[j, 2]
                row[2] = 1.0 if axis == 0 else 0.0
                row[3] = 1.0 if axis == 1 else 0.0
                row[4] = -uu
                row[5] = C[j, axis] - uu * C[j, 2]
                for p in range(6):
                    rp = row[p]
                    for q in range(p, 6):
                        DTD[p, q] += rp * row[q]
        for p in range(6):
            for q in range(p):
                DTD[p, q] = DTD[q, p]
        _, V = np.linalg.eigh(DTD)
        last = V[5, 0]
        if not abs(last) > 1e-300:
            continue
        c = V[0, 0] / last
        s = V[1, 0] / last
        tx, ty, tz = V[2, 0] / last, V[3, 0] / last, V[4, 0] / last

        # Step 5: points pushed onto their rays, scaled Procrustes (Umeyama).
        my = np.zeros(3)
        for j in range(n):
            x0 = C[j, 0] + c * A[j, 0] + s * B[j, 0] + tx
            x1 = C[j, 1] + c * A[j, 1] + s * B[j, 1] + ty
            x2 = C[j, 2] + c * A[j, 2] + s * B[j, 2] + tz
            dep = math.sqrt(x0 * x0 + x1 * x1 + x2 * x2)
            for k in range(3):
                Xc[j, k] = xv[j, k] * dep
                my[k] += Xc[j, k]
        my /= n
        S = np.zeros((3, 3))
        sx2 = 0.0
        for j in range(n):
            q0, q1, q2 = XXw[j, 0] - cx, XXw[j, 1] - cy, XXw[j, 2] - cz
            sx2 += q0 * q0 + q1 * q1 + q2 * q2
            for k in range(3):
                yk = Xc[j, k] - my[k]
                S[k, 0] += yk * q0
                S[k, 1] += yk * q1
                S[k, 2] += yk * q2
        S /= n
        sx2 /= n
        U, dvals, Vt = np.linalg.svd(S)
        R = U @ Vt
        d_last = dvals[2]
        if _det3(R) < 0:
            for k in range(3):
                U[k, 2] = -U[k, 2]
            R = U @ Vt
            d_last = -d_last
        sc = (dvals[0] + dvals[1] + d_last) / sx2 if sx2 > 0 else 1.0
        t0 = my[0] - sc * (R[0, 0] * cx + R[0, 1] * cy + R[0, 2] * cz)
        t1 = my[1] - sc * (R[1, 0] * cx + R[1, 1] * cy + R[1, 2] * cz)
        t2 = my[2] - sc * (R[2, 0] * cx + R[2, 1] * cy + R[2, 2] * cz)
        err = 0.0
        ok = True
        for j in range(n):
            X0 = R[0, 0] * XXw[j, 0] + R[0, 1] * XXw[j, 1] + R[0, 2] * XXw[j, 2] + t0
            X1 = R[1, 0] * XXw[j, 0] + R[1, 1] * XXw[j, 1] + R[1, 2] * XXw[j, 2] + t1
            X2 = R[2, 0] * XXw[j, 0] + R[2, 1] * XXw[j, 1] + R[2, 2] * XXw[j, 2] + t2
            if not X2 > 0:
                ok = False
                break
            eu = X0 / X2 - xx[j, 0]
            ev = X1 / X2 - xx[j, 1]
            err += math.sqrt(eu * eu + ev * ev)
        Rs[count] = R
        ts[count, 0], ts[count, 1], ts[count, 2] = t0, t1, t2
        errs[count] = err / n if ok and math.isfinite(err) else np.inf
        count += 1
    if count == 0:
        return 4, empty_R, empty_t, empty_e
    return 0, Rs[:count], ts[:count], errs[:count]


# ---------------------------------------------------------------------------------------------
# Refinement: pnp_refine.refine_pose (numpy reference ``refine_pose(..., backend="numpy")``)
# ---------------------------------------------------------------------------------------------
@njit(cache=True)
def _project_residual(R: np.ndarray, t: np.ndarray, X: np.ndarray, m: np.ndarray,
                      Xc: np.ndarray, r: np.ndarray) -> bool:
    """Xc = X R^T + t and the normalised residuals r (x0, y0, x1, ...); False when a point
    is not in front of the camera."""
    for i in range(X.shape[0]):
        for a in range(3):
            Xc[i, a] = X[i, 0] * R[a, 0] + X[i, 1] * R[a, 1] + X[i, 2] * R[a, 2] + t[a]
        if not Xc[i, 2] > 0:
            return False
    for i in range(X.shape[0]):
        r[2 * i] = Xc[i, 0] / Xc[i, 2] - m[i, 0]
        r[2 * i + 1] = Xc[i, 1] / Xc[i, 2] - m[i, 1]
    return True


@njit(cache=True)
def _rodrigues_k(w0: float, w1: float, w2: float) -> np.ndarray:
    theta = math.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
    K = np.zeros((3, 3))
    if theta < 1e-12:
        k0, k1, k2 = w0, w1, w2
    else:
        k0, k1, k2 = w0 / theta, w1 / theta, w2 / theta
    K[0, 1], K[0, 2] = -k2, k1
    K[1, 0], K[1, 2] = k2, -k0
    K[2, 0], K[2, 1] = -k1, k0
    if theta < 1e-12:
        return np.eye(3) + K
    return np.eye(3) + math.sin(theta) * K + (1 - math.cos(theta)) * (K @ K)


@njit(cache=True)
def refine_pose_core(R0: np.ndarray, t0: np.ndarray, X: np.ndarray, m: np.ndarray,
                     max_iterations: int, tol: float) -> tuple[np.ndarray, np.ndarray, bool]:
    """Levenberg-Marquardt of ``pnp_refine.refine_pose``: returns (R, t, refined); ``refined``
    False means the start pose has a point behind the camera (returned unchanged)."""
    n = X.shape[0]
    R = R0.copy()
    t = t0.copy()
    Xc = np.empty((n, 3))
    r = np.empty(2 * n)
    if not _project_residual(R, t, X, m, Xc, r):
        return R, t, False
    Xn = np.empty((n, 3))
    rn = np.empty(2 * n)
    J = np.empty((2 * n, 6))
    lam = 1e-3
    cost = float(r @ r)
    for _ in range(max_iterations):
        for i in range(n):
            iz = 1.0 / Xc[i, 2]
            a0, a1 = -Xc[i, 0] * iz * iz, -Xc[i, 1] * iz * iz
            v0, v1, v2 = Xc[i, 0] - t[0], Xc[i, 1] - t[1], Xc[i, 2] - t[2]
            # d(proj)/d(Xc) = [[iz, 0, a0], [0, iz, a1]]; d(Xc)/dw = -[R X]_x; d(Xc)/dt = I
            J[2 * i, 0] = -(a0 * -v1)
            J[2 * i, 1] = -(iz * -v2 + a0 * v0)
            J[2 * i, 2] = -(iz * v1)
            J[2 * i + 1, 0] = -(iz * v2 + a1 * -v1)
            J[2 * i + 1, 1] = -(a1 * v0)
            J[2 * i + 1, 2] = -(iz * -v0)
            J[2 * i, 3], J[2 * i, 4], J[2 * i, 5] = iz, 0.0, a0
            J[2 * i + 1, 3], J[2 * i + 1, 4], J[2 * i + 1, 5] = 0.0, iz, a1
        H = J.T @ J
        g = J.T @ r
        improved = False
        done = False
        for _ in range(8):
            A = H.copy()
            for k in range(6):
                A[k, k] += lam * (H[k, k] + 1e-12)
            try:
                step = -np.linalg.solve(A, g)
            except Exception:  # noqa: BLE001 - singular: numpy's LinAlgError
                lam *= 10
                continue
            R_new = _rodrigues_k(step[0], step[1], step[2]) @ R
            t_new = t + step[3:]
            if _project_residual(R_new, t_new, X, m, Xn, rn) and float(rn @ rn) < cost:
                R, t = R_new, t_new
                Xc[:], r[:] = Xn, rn
                new_cost = float(r @ r)
                done = cost - new_cost <= tol * max(cost, 1e-300)
                cost = new_cost
                lam = max(lam / 10, 1e-9)
                improved = True
                break
            lam *= 10
        if not improved or done:
            break
    U, _, Vt = np.linalg.svd(R)
    return U @ Vt, t, True
