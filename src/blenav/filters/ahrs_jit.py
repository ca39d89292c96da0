"""Compiled (numba) Madgwick AHRS and causal median: the numbers of the ``ahrs`` package, ~100x faster.

:func:`madgwick_run` loops over an IMU stream inside one compiled function; :func:`madgwick_step` is one
sample (the streaming path). Both reproduce ``ahrs.filters.Madgwick.updateIMU``/``updateMARG`` (ahrs
0.4.0) operation for operation: the same re-normalisations (``Quaternion(q)`` normalises its input, the
rotated magnetometer quaternion too), the same left-to-right Python float arithmetic, the norms as numpy's
``np.linalg.norm`` = sqrt of a BLAS dot (fused multiply-adds from the first element on, as OpenBLAS's
scalar tail computes it) and ``J.T @ f`` as a sum over the six residuals in order. Measured against
ahrs on a 384 s, 200 Hz session (tests/filters/test_attitude.py): the quaternions agree to ~1e-15 (bit-identical
on most samples; a BLAS built otherwise rounds some dot products differently, which stays at that level:
the filter is contracting).

:func:`causal_median_jit` is :func:`blenav.filters.median.causal_median` (np.median over the padded
sliding window: the middle element, the mean of the two middle ones for an even window, NaN when the
window holds a NaN) without the (T, d, w) window copy; same numbers bit for bit.

The first call compiles (cache=True: once per machine, then loaded from __pycache__ in ~0.1 s).
"""

from __future__ import annotations

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.extending import intrinsic


@intrinsic
def _fma(typingctx, a, b, c):
    """a * b + c with one rounding (llvm.fma: the instruction on x86-64 with FMA, a libm call otherwise)."""
    sig = types.float64(types.float64, types.float64, types.float64)

    def codegen(context, builder, signature, args):
        d = ir.DoubleType()
        fn = builder.module.declare_intrinsic("llvm.fma", [d], ir.FunctionType(d, [d, d, d]))
        return builder.call(fn, args)

    return sig, codegen


@njit(cache=True, inline="always")
def _norm2(a, b):
    return np.sqrt(_fma(b, b, _fma(a, a, 0.0)))


@njit(cache=True, inline="always")
def _norm3(a, b, c):
    return np.sqrt(_fma(c, c, _fma(b, b, _fma(a, a, 0.0))))


@njit(cache=True, inline="always")
def _norm4(a, b, c, d):
    return np.sqrt(_fma(d, d, _fma(c, c, _fma(b, b, _fma(a, a, 0.0)))))


@njit(cache=True, inline="always")
def _prod(pw, px, py, pz, qw, qx, qy, qz):
    """ahrs ``Quaternion.product``: the Hamilton product, evaluated left to right."""
    return (pw * qw - px * qx - py * qy - pz * qz,
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw)


@njit(cache=True)
def madgwick_step(q, gyr, acc, mag, use_mag, dt, gain, dt_default, out):
    """One ``Madgwick.updateMARG`` (``use_mag``) or ``updateIMU`` sample; q (4,) -> out (4,).

    ``dt_default``: the filter's ``Dt`` (ahrs' updateMARG falls back to updateIMU without ``dt`` when the
    magnetometer sample is zero)."""
    n = _norm4(q[0], q[1], q[2], q[3])
    qw, qx, qy, qz = q[0] / n, q[1] / n, q[2] / n, q[3] / n  # Quaternion(q)
    g0, g1, g2 = gyr[0], gyr[1], gyr[2]
    if _norm3(g0, g1, g2) == 0:
        out[0], out[1], out[2], out[3] = qw, qx, qy, qz
        return
    marg = use_mag
    if marg and _norm3(mag[0], mag[1], mag[2]) == 0:
        marg = False
        dt = dt_default
        n = _norm4(qw, qx, qy, qz)  # updateIMU's own Quaternion(q)
        qw, qx, qy, qz = qw / n, qx / n, qy / n, qz / n
    d0, d1, d2, d3 = _prod(qw, qx, qy, qz, 0.0, g0, g1, g2)  # q.product([0, *gyr])
    d0, d1, d2, d3 = 0.5 * d0, 0.5 * d1, 0.5 * d2, 0.5 * d3
    a_norm = _norm3(acc[0], acc[1], acc[2])
    if a_norm > 0:
        a0, a1, a2 = acc[0] / a_norm, acc[1] / a_norm, acc[2] / a_norm
        n = _norm4(qw, qx, qy, qz)
        w, x, y, z = qw / n, qx / n, qy / n, qz / n  # q / np.linalg.norm(q)
        f0 = 2.0 * (x * z - w * y) - a0
        f1 = 2.0 * (w * x + y * z) - a1
        f2 = 2.0 * (0.5 - x * x - y * y) - a2
        if marg:
            mn = _norm3(mag[0], mag[1], mag[2])
            m0, m1, m2 = mag[0] / mn, mag[1] / mn, mag[2] / mn
            mn = _norm4(0.0, m0, m1, m2)  # Quaternion([0, *m])
            pw, px, py, pz = 0.0 / mn, m0 / mn, m1 / mn, m2 / mn
            r0, r1, r2, r3 = _prod(pw, px, py, pz, qw, -qx, -qy, -qz)  # q_m.product(q.conj)
            h0, h1, h2, h3 = _prod(qw, qx, qy, qz, r0, r1, r2, r3)
            bx = _norm2(h1, h2)
            bz = h3
            f3 = 2.0 * bx * (0.5 - y * y - z * z) + 2.0 * bz * (x * z - w * y) - m0
            f4 = 2.0 * bx * (x * y - w * z) + 2.0 * bz * (w * x + y * z) - m1
            f5 = 2.0 * bx * (w * y + x * z) + 2.0 * bz * (0.5 - x * x - y * y) - m2
            fn = np.sqrt(_fma(f5, f5, _fma(f4, f4, _fma(f3, f3, _fma(f2, f2, _fma(f1, f1, _fma(f0, f0, 0.0)))))))
        else:
            fn = _norm3(f0, f1, f2)
        if fn > 0:
            # gradient = J.T @ f, J of eq. 26 (IMU) / eq. 32 (MARG)
            j00, j01, j02, j03 = -2.0 * y, 2.0 * z, -2.0 * w, 2.0 * x
            j10, j11, j12, j13 = 2.0 * x, 2.0 * w, 2.0 * z, 2.0 * y
            j20, j21, j22, j23 = 0.0, -4.0 * x, -4.0 * y, 0.0
            gr0 = _fma(j20, f2, _fma(j10, f1, _fma(j00, f0, 0.0)))
            gr1 = _fma(j21, f2, _fma(j11, f1, _fma(j01, f0, 0.0)))
            gr2 = _fma(j22, f2, _fma(j12, f1, _fma(j02, f0, 0.0)))
            gr3 = _fma(j23, f2, _fma(j13, f1, _fma(j03, f0, 0.0)))
            if marg:
                j30, j31, j32, j33 = (-2.0 * bz * y, 2.0 * bz * z, -4.0 * bx * y - 2.0 * bz * w,
                                      -4.0 * bx * z + 2.0 * bz * x)
                j40, j41, j42, j43 = (-2.0 * bx * z + 2.0 * bz * x, 2.0 * bx * y + 2.0 * bz * w,
                                      2.0 * bx * x + 2.0 * bz * z, -2.0 * bx * w + 2.0 * bz * y)
                j50, j51, j52, j53 = (2.0 * bx * y, 2.0 * bx * z - 4.0 * bz * x, 2.0 * bx * w - 4.0 * bz * y,
                                      2.0 * bx * x)
                gr0 = _fma(j50, f5, _fma(j40, f4, _fma(j30, f3, gr0)))
                gr1 = _fma(j51, f5, _fma(j41, f4, _fma(j31, f3, gr1)))
                gr2 = _fma(j52, f5, _fma(j42, f4, _fma(j32, f3, gr2)))
                gr3 = _fma(j53, f5, _fma(j43, f4, _fma(j33, f3, gr3)))
            gn = _norm4(gr0, gr1, gr2, gr3)
            gr0, gr1, gr2, gr3 = gr0 / gn, gr1 / gn, gr2 / gn, gr3 / gn
            d0 = d0 - gain * gr0
            d1 = d1 - gain * gr1
            d2 = d2 - gain * gr2
            d3 = d3 - gain * gr3
    n0, n1, n2, n3 = qw + d0 * dt, qx + d1 * dt, qy + d2 * dt, qz + d3 * dt
    n = _norm4(n0, n1, n2, n3)
    out[0], out[1], out[2], out[3] = n0 / n, n1 / n, n2 / n, n3 / n


@njit(cache=True)
def madgwick_run(Q, k0, t, gyr, acc, mag, idx, gain, dt_default, stop_on_new_mag, mag_seen):
    """Samples k = k0, k0+1, ... of a stream into Q (T, 4), Q[k0 - 1] being the state before: one
    :func:`madgwick_step` each, with ``mag[idx[k]]`` (idx < 0: no magnetometer sample yet, IMU update).

    Stops before a sample that needs the caller (returns its k; T when done): the first magnetometer sample
    when ``mag_seen`` is False (heading alignment), and, with ``stop_on_new_mag``, every sample whose
    magnetometer sample is new (the compass-disagreement reset)."""
    T = len(t)
    empty = np.zeros(3)
    for k in range(k0, T):
        j = idx[k]
        if j >= 0:
            if not mag_seen:
                return k
            if stop_on_new_mag and j != idx[k - 1]:
                return k
            madgwick_step(Q[k - 1], gyr[k], acc[k], mag[j], True, t[k] - t[k - 1], gain, dt_default, Q[k])
        else:
            madgwick_step(Q[k - 1], gyr[k], acc[k], empty, False, t[k] - t[k - 1], gain, dt_default, Q[k])
    return T


@njit(cache=True)
def causal_median_jit(x, window):
    """(T, d) -> (T, d): np.median over x[k-w+1 .. k] per column, padded with copies of x[0]."""
    T, D = x.shape
    out = np.empty((T, D))
    buf = np.empty(window)
    h = window // 2
    for k in range(T):
        for c in range(D):
            nan = False
            for i in range(window):
                j = k - window + 1 + i
                v = x[j if j > 0 else 0, c]
                if v != v:
                    nan = True
                # insertion sort
                p = i
                while p > 0 and buf[p - 1] > v:
                    buf[p] = buf[p - 1]
                    p -= 1
                buf[p] = v
            if nan:
                out[k, c] = np.nan
            elif window % 2:
                out[k, c] = buf[h]
            else:
                out[k, c] = (buf[h - 1] + buf[h]) / 2
    return out
