"""Rigid transforms of gaussians with their motion, exact in Deformable-3DGS's semantics.

A part moved by rotation R and translation T renders at time t as R (m + d(t)) + T. Since a
deformation adds offsets (means + d_xyz, normalize(q) + d_rot, exp(s) + d_scale), the moved
part is again canonical gaussians plus offsets: means R m + T with offsets R d_xyz, unit
quaternions q_R * normalize(q) with offsets q_R * d_rot (the product is linear in its second
factor), scales and their offsets unchanged. ``TransformedDeformation`` evaluates the part's
own deformation at its own canonical positions and time and rotates the offsets, so nothing
is baked or approximated. View-dependent colour turns with the part: each SH band is
rotated by the matrix that maps the band's basis under R (found by least squares on sampled
directions; a band is closed under rotation, so the fit is exact to rounding).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch
from torch import nn

from trase.gaussians import GaussianModel
from trase.render.sh import eval_sh


def quat_mul(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Hamilton product of wxyz quaternions, a [4] or [N, 4] times b [N, 4] -> [N, 4]."""
    a = a.expand_as(b)
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack([
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ], dim=-1)


def rotmat_to_quat(R: np.ndarray) -> np.ndarray:
    """Rotation matrix [3, 3] -> unit quaternion [4] wxyz (w >= 0)."""
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(np.asarray(R, dtype=np.float64)).as_quat()
    q = np.array([w, x, y, z])
    return q if w >= 0 else -q


@dataclasses.dataclass(frozen=True)
class RigidTransform:
    """x -> R x + T. ``rotation`` [3, 3] orthonormal with det +1, ``translation`` [3]."""

    rotation: tuple = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    translation: tuple = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        from trase.edit.model import EditError

        R = np.asarray(self.rotation, dtype=np.float64)
        T = np.asarray(self.translation, dtype=np.float64)
        if R.shape != (3, 3) or T.shape != (3,) or not (np.isfinite(R).all() and np.isfinite(T).all()):
            raise EditError(f"a rigid transform needs a finite 3x3 rotation and a 3-vector, got {R.shape}, {T.shape}")
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-5) or np.linalg.det(R) < 0:
            raise EditError("the rotation of a rigid transform must be orthonormal with determinant +1")
        object.__setattr__(self, "rotation", tuple(map(tuple, R.tolist())))
        object.__setattr__(self, "translation", tuple(T.tolist()))

    @classmethod
    def from_euler(cls, degrees_xyz=(0.0, 0.0, 0.0), translation=(0.0, 0.0, 0.0)) -> RigidTransform:
        from scipy.spatial.transform import Rotation

        R = Rotation.from_euler("xyz", np.asarray(degrees_xyz, dtype=np.float64), degrees=True).as_matrix()
        return cls(R, tuple(np.asarray(translation, dtype=np.float64)))

    @property
    def R(self) -> torch.Tensor:  # [3, 3] float32
        return torch.tensor(self.rotation, dtype=torch.float32)

    @property
    def T(self) -> torch.Tensor:  # [3] float32
        return torch.tensor(self.translation, dtype=torch.float32)

    @property
    def is_identity(self) -> bool:
        return np.allclose(self.rotation, np.eye(3)) and np.allclose(self.translation, 0.0)

    def quaternion(self) -> torch.Tensor:  # [4] wxyz
        return torch.tensor(rotmat_to_quat(np.asarray(self.rotation)), dtype=torch.float32)

    def apply_points(self, x: torch.Tensor) -> torch.Tensor:  # [N, 3] -> [N, 3]
        return x @ self.R.T + self.T

    def invert_points(self, x: torch.Tensor) -> torch.Tensor:  # [N, 3] -> [N, 3]
        return (x - self.T) @ self.R


def sh_rotation(degree: int, R: np.ndarray, n_dirs: int = 64) -> list[np.ndarray]:
    """Per band l = 1..degree, the matrix M_l [(2l+1), (2l+1)] with Y_l(R^T d) = M_l Y_l(d) for
    the 3DGS basis; coefficients c of a band become M_l^T c when the object turns by R."""
    rng = np.random.default_rng(0)
    d = rng.normal(size=(n_dirs, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    d_rot = d @ np.asarray(R, dtype=np.float64)  # rows R^T d
    K = (degree + 1) ** 2

    def basis(dirs: np.ndarray) -> np.ndarray:  # [M, K]
        dirs_t = torch.as_tensor(dirs, dtype=torch.float64)
        cols = []
        for k in range(K):
            sh = torch.zeros(dirs.shape[0], K, 3, dtype=torch.float64)
            sh[:, k, 0] = 1.0
            cols.append(eval_sh(degree, sh, dirs_t)[:, 0])
        return torch.stack(cols, dim=1).numpy()

    B, B_rot = basis(d), basis(d_rot)
    out = []
    for lvl in range(1, degree + 1):
        sl = slice(lvl * lvl, (lvl + 1) ** 2)
        # B_rot[:, sl] = B[:, sl] @ M^T  ->  least squares for M^T
        Mt, *_ = np.linalg.lstsq(B[:, sl], B_rot[:, sl], rcond=None)
        out.append(Mt.T)
    return out


def transform_gaussians(g: GaussianModel, tf: RigidTransform) -> GaussianModel:
    """Canonical gaussians moved by ``tf`` (means, rotations, view-dependent colour)."""
    out = g.copy()
    if tf.is_identity:
        return out
    with torch.no_grad():
        out.means.copy_(tf.apply_points(g.means))
        out.quats.copy_(quat_mul(tf.quaternion(), g.rotations))
        if g.max_sh_degree > 0:
            rest = g.sh_rest.detach().clone()  # [N, K-1, 3]
            for lvl, M in enumerate(sh_rotation(g.max_sh_degree, np.asarray(tf.rotation)), start=1):
                sl = slice(lvl * lvl - 1, (lvl + 1) ** 2 - 1)
                Mt = torch.as_tensor(M.T, dtype=rest.dtype)  # c' = M^T c, per colour channel
                rest[:, sl] = torch.einsum("ij,njc->nic", Mt, rest[:, sl])
            out.sh_rest.copy_(rest)
    return out


class StaticDeformation(nn.Module):
    """No motion: zero offsets (a static part inside a composition)."""

    def forward(self, xyz: torch.Tensor, t):
        n = xyz.shape[0]
        return xyz.new_zeros(n, 3), xyz.new_zeros(n, 4), xyz.new_zeros(n, 3)

    def rows(self, mask: torch.Tensor) -> StaticDeformation:
        return self


class TransformedDeformation(nn.Module):
    """A part's own deformation seen after the rigid transform ``tf`` and a time shift: at
    scene time t the part shows its time clamp(t + time_offset, 0, 1)."""

    def __init__(self, inner, tf: RigidTransform, time_offset: float = 0.0) -> None:
        super().__init__()
        self.inner = inner if inner is not None else StaticDeformation()
        self.tf = tf
        self.time_offset = float(time_offset)
        self.scale_rule = getattr(self.inner, "scale_rule", None)  # d_scale passes through unchanged

    def forward(self, xyz: torch.Tensor, t):
        t = float(t.reshape(-1)[0]) if torch.is_tensor(t) else float(t)
        local = self.tf.invert_points(xyz)  # the canonical positions the part was trained at
        d_xyz, d_rot, d_scale = self.inner(local, min(max(t + self.time_offset, 0.0), 1.0))
        R = self.tf.R.to(d_xyz.dtype)
        return d_xyz @ R.T, quat_mul(self.tf.quaternion().to(d_rot.dtype), d_rot), d_scale

    def rows(self, mask: torch.Tensor) -> TransformedDeformation:
        from trase.edit.model import subset_deformation

        return TransformedDeformation(subset_deformation(self.inner, mask.numpy()), self.tf, self.time_offset)
