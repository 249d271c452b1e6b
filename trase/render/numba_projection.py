"""EWA projection in numba with a hand-written backward (the numba backend's projection).

Same math, clamps and culling rules as the torch reference in projection.py (which the tests
compare against, values and gradients); see that module for the formulas. Why a second
implementation: at 20k gaussians the reference's ~40 small float64 torch ops and their
autograd graph cost as much as compositing itself once compositing was vectorised.

Backward, per gaussian (float64), reverse of the forward chain:
  conic (a', b', c') = (c, -b, a) / det  ->  d cov entries (a, b, c)
  cov = T Sigma T^T, T = J R_w           ->  dT = (G + G^T) T Sigma, dSigma = T^T G T
  Sigma = M M^T, M = R(q) diag(s)        ->  dM = (dSigma + dSigma^T) M -> ds, dR -> dq
  J(x/z, y/z, z) and (u, v)             ->  d camera point p -> d mean = R_w^T dp
"""

from __future__ import annotations

import math

import numpy as np
import torch
from numba import njit, prange

from trase.camera import Camera
from trase.render.projection import EPS2D, Projected, jacobian_clamp, screen_rects


@njit(inline="always")
def _rotmat(qw, qx, qy, qz, R):
    R[0, 0] = 1 - 2 * (qy * qy + qz * qz)
    R[0, 1] = 2 * (qx * qy - qw * qz)
    R[0, 2] = 2 * (qx * qz + qw * qy)
    R[1, 0] = 2 * (qx * qy + qw * qz)
    R[1, 1] = 1 - 2 * (qx * qx + qz * qz)
    R[1, 2] = 2 * (qy * qz - qw * qx)
    R[2, 0] = 2 * (qx * qz - qw * qy)
    R[2, 1] = 2 * (qy * qz + qw * qx)
    R[2, 2] = 1 - 2 * (qx * qx + qy * qy)


@njit(inline="always")
def _work_arrays():
    """Per-gaussian scratch filled by _setup: T (2x3), Sig, M, R (3x3)."""
    return np.empty((2, 3)), np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3))


@njit(inline="always")
def _setup(n, means, quats, scales, Rw, tw, near, fx, fy, cx, cy, skew, xlo, xhi, ylo, yhi, T, Sig, M, R):
    """Shared forward algebra for gaussian n: fills T (2x3), Sig, M, R (3x3); returns
    (p0, p1, z, in_front, xn, yn, xc, yc, qnorm, qw, qx, qy, qz)."""
    m0, m1, m2 = means[n, 0], means[n, 1], means[n, 2]
    p0 = Rw[0, 0] * m0 + Rw[0, 1] * m1 + Rw[0, 2] * m2 + tw[0]
    p1 = Rw[1, 0] * m0 + Rw[1, 1] * m1 + Rw[1, 2] * m2 + tw[1]
    z = Rw[2, 0] * m0 + Rw[2, 1] * m1 + Rw[2, 2] * m2 + tw[2]
    in_front = z > near
    zs = z if in_front else 1.0
    xn = p0 / zs
    yn = p1 / zs
    xc = min(max(xn, xlo), xhi)
    yc = min(max(yn, ylo), yhi)
    J00, J01, J02 = fx / zs, skew / zs, -(fx * xc + skew * yc) / zs
    J11, J12 = fy / zs, -fy * yc / zs
    for k in range(3):
        T[0, k] = J00 * Rw[0, k] + J01 * Rw[1, k] + J02 * Rw[2, k]
        T[1, k] = J11 * Rw[1, k] + J12 * Rw[2, k]
    qw, qx, qy, qz = quats[n, 0], quats[n, 1], quats[n, 2], quats[n, 3]
    qnorm = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    qd = max(qnorm, 1e-12)
    qw, qx, qy, qz = qw / qd, qx / qd, qy / qd, qz / qd
    _rotmat(qw, qx, qy, qz, R)
    for i in range(3):
        for k in range(3):
            M[i, k] = R[i, k] * scales[n, k]
    for i in range(3):
        for k in range(3):
            Sig[i, k] = M[i, 0] * M[k, 0] + M[i, 1] * M[k, 1] + M[i, 2] * M[k, 2]
    return p0, p1, z, in_front, xn, yn, xc, yc, qnorm, qw, qx, qy, qz


@njit(inline="always")
def _cov2d(T, Sig):
    """-> (cov00, cov01, cov11) of T Sig T^T."""
    c00 = 0.0
    c01 = 0.0
    c11 = 0.0
    for i in range(3):
        for k in range(3):
            s = Sig[i, k]
            c00 += T[0, i] * s * T[0, k]
            c01 += T[0, i] * s * T[1, k]
            c11 += T[1, i] * s * T[1, k]
    return c00, c01, c11


@njit(parallel=True, cache=True)
def project_forward(means, quats, scales, Rw, tw, near, fx, fy, cx, cy, skew, xlo, xhi, ylo, yhi,
                    means2d, conics, depths, ok_out, lam_out):
    """means/quats/scales float64 -> means2d [N, 2], conics [N, 3], depths [N], ok [N] bool,
    lam_out [N] largest eigenvalue of the dilated 2D covariance (for the screen radius)."""
    for n in prange(means.shape[0]):
        T, Sig, M, R = _work_arrays()
        _p0, _p1, z, in_front, xn, yn, _xc, _yc, _qn, _qw, _qx, _qy, _qz = _setup(
            n, means, quats, scales, Rw, tw, near, fx, fy, cx, cy, skew, xlo, xhi, ylo, yhi, T, Sig, M, R)
        c00, c01, c11 = _cov2d(T, Sig)
        a = c00 + EPS2D
        b = c01
        c = c11 + EPS2D
        det = a * c - b * b
        ok = in_front and det > 0.0 and math.isfinite(det)
        depths[n] = z
        ok_out[n] = ok
        if ok:
            conics[n, 0] = c / det
            conics[n, 1] = -b / det
            conics[n, 2] = a / det
            means2d[n, 0] = fx * xn + skew * yn + cx
            means2d[n, 1] = fy * yn + cy
            mid = 0.5 * (a + c)
            lam_out[n] = mid + math.sqrt(max(mid * mid - det, 0.1))
        else:
            conics[n, 0] = 0.0
            conics[n, 1] = 0.0
            conics[n, 2] = 0.0
            means2d[n, 0] = 0.0
            means2d[n, 1] = 0.0
            lam_out[n] = 0.0


@njit(parallel=True, cache=True)
def project_backward(means, quats, scales, Rw, tw, near, fx, fy, cx, cy, skew, xlo, xhi, ylo, yhi,
                     ok_in, g_m2d, g_con, g_dep, d_means, d_quats, d_scales):
    """Gradients of means2d / conics / depths -> d_means [N, 3], d_quats [N, 4], d_scales [N, 3]."""
    for n in prange(means.shape[0]):
        T, Sig, M, R = _work_arrays()
        _p0, _p1, z, _in_front, xn, yn, xc, yc, qnorm, qw, qx, qy, qz = _setup(
            n, means, quats, scales, Rw, tw, near, fx, fy, cx, cy, skew, xlo, xhi, ylo, yhi, T, Sig, M, R)
        dp0 = 0.0
        dp1 = 0.0
        dp2 = g_dep[n]
        for k in range(4):
            d_quats[n, k] = 0.0
        for k in range(3):
            d_scales[n, k] = 0.0
        if ok_in[n]:
            c00, c01, c11 = _cov2d(T, Sig)
            A = c00 + EPS2D
            B = c01
            Cc = c11 + EPS2D
            det = A * Cc - B * B
            id1 = 1.0 / det
            id2 = id1 * id1
            ga, gb, gc = g_con[n, 0], g_con[n, 1], g_con[n, 2]
            dA = ga * (-Cc * Cc * id2) + gb * (B * Cc * id2) + gc * (id1 - A * Cc * id2)
            dB = ga * (2.0 * B * Cc * id2) + gb * (-id1 - 2.0 * B * B * id2) + gc * (2.0 * A * B * id2)
            dC = ga * (id1 - A * Cc * id2) + gb * (A * B * id2) + gc * (-A * A * id2)
            # G = d cov as a (non-symmetric) 2x2: only cov[0, 1] is read for b
            G00, G01, G10, G11 = dA, dB, 0.0, dC
            # dSigma = T^T G T ; dT = (G + G^T) T Sigma
            dS = np.empty((3, 3))
            for i in range(3):
                for k in range(3):
                    dS[i, k] = (T[0, i] * (G00 * T[0, k] + G01 * T[1, k])
                                + T[1, i] * (G10 * T[0, k] + G11 * T[1, k]))
            TS = np.empty((2, 3))
            for r in range(2):
                for k in range(3):
                    TS[r, k] = T[r, 0] * Sig[0, k] + T[r, 1] * Sig[1, k] + T[r, 2] * Sig[2, k]
            S00, S01, S11 = 2.0 * G00, G01 + G10, 2.0 * G11
            dT = np.empty((2, 3))
            for k in range(3):
                dT[0, k] = S00 * TS[0, k] + S01 * TS[1, k]
                dT[1, k] = S01 * TS[0, k] + S11 * TS[1, k]
            # T = J Rw -> dJ = dT Rw^T (only the 5 used entries of J)
            dJ00 = dT[0, 0] * Rw[0, 0] + dT[0, 1] * Rw[0, 1] + dT[0, 2] * Rw[0, 2]
            dJ01 = dT[0, 0] * Rw[1, 0] + dT[0, 1] * Rw[1, 1] + dT[0, 2] * Rw[1, 2]
            dJ02 = dT[0, 0] * Rw[2, 0] + dT[0, 1] * Rw[2, 1] + dT[0, 2] * Rw[2, 2]
            dJ11 = dT[1, 0] * Rw[1, 0] + dT[1, 1] * Rw[1, 1] + dT[1, 2] * Rw[1, 2]
            dJ12 = dT[1, 0] * Rw[2, 0] + dT[1, 1] * Rw[2, 1] + dT[1, 2] * Rw[2, 2]
            iz = 1.0 / z
            iz2 = iz * iz
            dz = (-dJ00 * fx - dJ01 * skew + dJ02 * (fx * xc + skew * yc) - dJ11 * fy + dJ12 * fy * yc) * iz2
            dxc = -dJ02 * fx * iz
            dyc = -(dJ02 * skew + dJ12 * fy) * iz
            dxn = dxc if (xlo <= xn <= xhi) else 0.0  # torch.clamp passes the gradient inclusively
            dyn = dyc if (ylo <= yn <= yhi) else 0.0
            du, dv = g_m2d[n, 0], g_m2d[n, 1]
            dxn += du * fx
            dyn += du * skew + dv * fy
            dp0 = dxn * iz
            dp1 = dyn * iz
            dp2 += dz - (dxn * xn + dyn * yn) * iz
            # Sigma = M M^T -> dM = (dS + dS^T) M ; M = R diag(s)
            dR = np.empty((3, 3))
            for i in range(3):
                for k in range(3):
                    dM = 0.0
                    for j in range(3):
                        dM += (dS[i, j] + dS[j, i]) * M[j, k]
                    dR[i, k] = dM * scales[n, k]
                    d_scales[n, k] += dM * R[i, k]
            # R(q_hat): partial derivatives of the rotation formula
            dqw = 2.0 * (-qz * dR[0, 1] + qy * dR[0, 2] + qz * dR[1, 0] - qx * dR[1, 2] - qy * dR[2, 0] + qx * dR[2, 1])
            dqx = 2.0 * (qy * dR[0, 1] + qz * dR[0, 2] + qy * dR[1, 0] - 2.0 * qx * dR[1, 1] - qw * dR[1, 2]
                         + qz * dR[2, 0] + qw * dR[2, 1] - 2.0 * qx * dR[2, 2])
            dqy = 2.0 * (-2.0 * qy * dR[0, 0] + qx * dR[0, 1] + qw * dR[0, 2] + qx * dR[1, 0] + qz * dR[1, 2]
                         - qw * dR[2, 0] + qz * dR[2, 1] - 2.0 * qy * dR[2, 2])
            dqz = 2.0 * (-2.0 * qz * dR[0, 0] - qw * dR[0, 1] + qx * dR[0, 2] + qw * dR[1, 0] - 2.0 * qz * dR[1, 1]
                         + qy * dR[1, 2] + qx * dR[2, 0] + qy * dR[2, 1])
            # q_hat = q / max(|q|, 1e-12)
            if qnorm > 1e-12:
                dot = dqw * qw + dqx * qx + dqy * qy + dqz * qz
                d_quats[n, 0] = (dqw - qw * dot) / qnorm
                d_quats[n, 1] = (dqx - qx * dot) / qnorm
                d_quats[n, 2] = (dqy - qy * dot) / qnorm
                d_quats[n, 3] = (dqz - qz * dot) / qnorm
            else:
                d_quats[n, 0] = dqw / 1e-12
                d_quats[n, 1] = dqx / 1e-12
                d_quats[n, 2] = dqy / 1e-12
                d_quats[n, 3] = dqz / 1e-12
        for k in range(3):
            d_means[n, k] = Rw[0, k] * dp0 + Rw[1, k] * dp1 + Rw[2, k] * dp2


def _camera_args(camera: Camera, near: float):
    Rw = np.ascontiguousarray(camera.w2c[:3, :3], dtype=np.float64)
    tw = np.ascontiguousarray(camera.w2c[:3, 3], dtype=np.float64)
    return (Rw, tw, float(near), float(camera.fx), float(camera.fy), float(camera.cx), float(camera.cy),
            float(camera.K[0, 1]), *jacobian_clamp(camera))


def _np64(t: torch.Tensor) -> np.ndarray:
    return np.ascontiguousarray(t.detach().to("cpu", torch.float64).numpy())


class _Project(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means, quats, scales, cam_args):
        m, q, s = _np64(means), _np64(quats), _np64(scales)
        n = m.shape[0]
        m2d = np.empty((n, 2))
        con = np.empty((n, 3))
        dep = np.empty(n)
        ok = np.empty(n, np.bool_)
        lam = np.empty(n)
        project_forward(m, q, s, *cam_args, m2d, con, dep, ok, lam)
        ctx.state = (m, q, s, cam_args, ok)
        ctx.dtypes = (means.dtype, quats.dtype, scales.dtype)
        ok_t, lam_t = torch.from_numpy(ok), torch.from_numpy(lam)
        ctx.mark_non_differentiable(ok_t, lam_t)
        return torch.from_numpy(m2d), torch.from_numpy(con), torch.from_numpy(dep), ok_t, lam_t

    @staticmethod
    def backward(ctx, g_m2d, g_con, g_dep, _g_ok, _g_lam):
        m, q, s, cam_args, ok = ctx.state
        n = m.shape[0]

        def arr(g, shape):
            return np.zeros(shape) if g is None else _np64(g)

        dm = np.empty((n, 3))
        dq = np.empty((n, 4))
        ds = np.empty((n, 3))
        project_backward(m, q, s, *cam_args, ok, arr(g_m2d, (n, 2)), arr(g_con, (n, 3)), arr(g_dep, (n,)), dm, dq, ds)
        dt_m, dt_q, dt_s = ctx.dtypes
        return torch.from_numpy(dm).to(dt_m), torch.from_numpy(dq).to(dt_q), torch.from_numpy(ds).to(dt_s), None


def project_gaussians_numba(
    means: torch.Tensor,  # [N, 3]
    quats: torch.Tensor,  # [N, 4] wxyz
    scales: torch.Tensor,  # [N, 3] positive
    camera: Camera,
    near: float = 0.01,
    tile_size: int = 16,
    dtype: torch.dtype | None = None,
) -> Projected:
    """Same contract and results as projection.project_gaussians (CPU tensors)."""
    out_dtype = dtype or means.dtype
    m2d, con, dep, ok, lam = _Project.apply(means, quats, scales, _camera_args(camera, near))
    with torch.no_grad():
        radii, rects = screen_rects(m2d, lam, ok, camera, tile_size)
    return Projected(means2d=m2d.to(out_dtype), conics=con.to(out_dtype), depths=dep.to(out_dtype),
                     radii=radii, rects=rects)
