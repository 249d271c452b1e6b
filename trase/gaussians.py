"""Canonical 3D gaussians as trainable parameters, PLY I/O, densification with Adam state.

Parameters (N gaussians, K = (max_sh_degree + 1)^2 SH coefficients):
    means [N, 3], log_scales [N, 3], quats [N, 4] (wxyz, not necessarily unit),
    opacity_logits [N], sh_dc [N, 1, 3], sh_rest [N, K-1, 3], optional features [N, D].
The DC and higher SH bands are separate parameters because 3DGS trains them with different
learning rates; ``sh`` concatenates them ([N, K, 3], sh[:, 0] is the DC term).

PLY files use the 3DGS attribute order (x, y, z, nx, ny, nz, f_dc_0..2, f_rest_*, opacity,
scale_0..2, rot_0..3) and TRASE's feature columns ``gaussian_feats_{i}``; f_rest is stored
channel-major (all red coefficients, then green, then blue), as 3DGS does.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import torch
from torch import nn

from trase.io import atomic_path

SH_C0 = 0.28209479177387814  # Y_0^0; colour = SH_C0 * dc + 0.5


class GaussianFileError(ValueError):
    """A gaussian PLY that cannot be read; the message names the file and the problem."""

    user_facing = True


def rgb_to_sh_dc(rgb):
    """RGB in [0, 1] -> SH DC coefficient (inverse of colour = SH_C0 * dc + 0.5)."""
    return (rgb - 0.5) / SH_C0


def sh_dc_to_rgb(dc):
    return dc * SH_C0 + 0.5


def inverse_sigmoid(x: torch.Tensor) -> torch.Tensor:
    x = x.clamp(1e-6, 1 - 1e-6)
    return torch.log(x / (1 - x))


def quat_to_rotmat(q: torch.Tensor) -> torch.Tensor:
    """Unit quaternions [N, 4] wxyz -> rotation matrices [N, 3, 3]."""
    w, x, y, z = q.unbind(-1)
    return torch.stack(
        [
            1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
        ],
        dim=-1,
    ).reshape(q.shape[:-1] + (3, 3))


_PARAM_NAMES = ("means", "log_scales", "quats", "opacity_logits", "sh_dc", "sh_rest", "features")


class GaussianModel(nn.Module):
    """Canonical gaussians. ``active_sh_degree`` is the degree rendered now (grows in training)."""

    def __init__(
        self,
        means: torch.Tensor,
        log_scales: torch.Tensor,
        quats: torch.Tensor,
        opacity_logits: torch.Tensor,
        sh: torch.Tensor,
        features: torch.Tensor | None = None,
        active_sh_degree: int | None = None,
    ) -> None:
        super().__init__()
        n = means.shape[0]
        sh = torch.as_tensor(sh, dtype=torch.float32)
        if sh.dim() == 2:  # [N, 3] DC only
            sh = sh[:, None, :]
        k = sh.shape[1]
        deg = round(math.sqrt(k)) - 1
        if (deg + 1) ** 2 != k or sh.shape[2] != 3:
            raise ValueError(f"sh must be [N, (d+1)^2, 3], got {tuple(sh.shape)}")
        shapes = {
            "means": (tuple(means.shape), (n, 3)),
            "log_scales": (tuple(log_scales.shape), (n, 3)),
            "quats": (tuple(quats.shape), (n, 4)),
            "opacity_logits": (tuple(opacity_logits.shape), (n,)),
            "sh": (tuple(sh.shape[:1]), (n,)),
        }
        for name, (got, want) in shapes.items():
            if got != want:
                raise ValueError(f"GaussianModel: {name} has shape {got}, expected {want}")
        if features is not None and (features.dim() != 2 or features.shape[0] != n):
            raise ValueError(f"GaussianModel: features must be [N={n}, D], got {tuple(features.shape)}")
        f32 = lambda t: nn.Parameter(torch.as_tensor(t, dtype=torch.float32).detach().clone().contiguous())
        self.means = f32(means)
        self.log_scales = f32(log_scales)
        self.quats = f32(quats)
        self.opacity_logits = f32(opacity_logits)
        self.sh_dc = f32(sh[:, :1])
        self.sh_rest = f32(sh[:, 1:])
        self.features = f32(features) if features is not None else None
        self.max_sh_degree = deg
        self.active_sh_degree = deg if active_sh_degree is None else min(int(active_sh_degree), deg)

    # -- construction --------------------------------------------------------------------
    @classmethod
    def from_points(
        cls,
        points: np.ndarray,
        colors: np.ndarray | None = None,
        sh_degree: int = 3,
        feature_dim: int = 0,
        seed: int = 0,
    ) -> GaussianModel:
        """3DGS initialisation from a point cloud [N, 3] (colours [N, 3] in [0, 1] or grey).

        Isotropic scale = sqrt of the mean squared distance to the 3 nearest neighbours (as
        3DGS's distCUDA2), opacity 0.1, identity rotation, higher SH bands zero. Features,
        when asked for, are initialised as TRASE does: RGB2SH(uniform[0, 1)).
        """
        from scipy.spatial import cKDTree

        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if pts.shape[0] == 0 or not np.isfinite(pts).all():
            raise ValueError("from_points: the point cloud is empty or has non-finite coordinates")
        n = pts.shape[0]
        if n > 1:
            k = min(4, n)
            d, _ = cKDTree(pts).query(pts, k=k)
            d2 = np.mean(np.square(d[:, 1:]), axis=1)
        else:
            d2 = np.ones(1)
        d2 = np.maximum(d2, 1e-7)
        log_s = np.log(np.sqrt(d2))[:, None].repeat(3, axis=1)
        if colors is None:
            colors = np.full((n, 3), 0.5)
        colors = np.clip(np.asarray(colors, dtype=np.float64).reshape(n, 3), 0.0, 1.0)
        sh = np.zeros((n, (sh_degree + 1) ** 2, 3))
        sh[:, 0] = rgb_to_sh_dc(colors)
        quats = np.zeros((n, 4))
        quats[:, 0] = 1.0
        logits = np.full(n, math.log(0.1 / 0.9))
        feats = None
        if feature_dim > 0:
            g = torch.Generator().manual_seed(seed)
            feats = rgb_to_sh_dc(torch.rand(n, feature_dim, generator=g))
        t = lambda a: torch.as_tensor(a, dtype=torch.float32)
        return cls(t(pts), t(log_s), t(quats), t(logits), t(sh), feats, active_sh_degree=0)

    # -- activations ---------------------------------------------------------------------
    @property
    def num_gaussians(self) -> int:
        return int(self.means.shape[0])

    @property
    def scales(self) -> torch.Tensor:
        return torch.exp(self.log_scales)

    @property
    def opacities(self) -> torch.Tensor:
        return torch.sigmoid(self.opacity_logits)

    @property
    def rotations(self) -> torch.Tensor:
        """Unit quaternions [N, 4] wxyz (a zero quaternion becomes identity, not NaN)."""
        q = self.quats
        norm = q.norm(dim=-1, keepdim=True)
        ident = torch.zeros_like(q)
        ident[:, 0] = 1.0
        return torch.where(norm > 1e-12, q / norm.clamp_min(1e-12), ident)

    @property
    def sh(self) -> torch.Tensor:
        """[N, K, 3] all SH coefficients, DC first."""
        return torch.cat([self.sh_dc, self.sh_rest], dim=1)

    def sh_for_render(self) -> torch.Tensor:
        """[N, (active+1)^2, 3]: only the bands currently trained."""
        k = (self.active_sh_degree + 1) ** 2
        return self.sh[:, :k]

    @property
    def colors_dc(self) -> torch.Tensor:
        """[N, 3] view-independent colour of each gaussian."""
        return sh_dc_to_rgb(self.sh_dc[:, 0])

    def param_tensors(self) -> dict[str, nn.Parameter]:
        """Per-gaussian parameters by name (features only when present)."""
        out = {}
        for name in _PARAM_NAMES:
            p = getattr(self, name)
            if p is not None:
                out[name] = p
        return out

    # -- PLY I/O -------------------------------------------------------------------------
    def ply_attribute_names(self) -> list[str]:
        names = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
        names += [f"f_rest_{i}" for i in range(3 * self.sh_rest.shape[1])]
        names += ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
        if self.features is not None:
            names += [f"gaussian_feats_{i}" for i in range(self.features.shape[1])]
        return names

    def save_ply(self, path: str | Path) -> None:
        """Write the 3DGS-layout PLY atomically (temp file in the same folder, then rename)."""
        from plyfile import PlyData, PlyElement

        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        with torch.no_grad():
            n = self.num_gaussians
            cols = [
                self.means.cpu().numpy(),
                np.zeros((n, 3), np.float32),
                self.sh_dc[:, 0].cpu().numpy(),
                self.sh_rest.transpose(1, 2).reshape(n, -1).cpu().numpy(),  # channel-major
                self.opacity_logits[:, None].cpu().numpy(),
                self.log_scales.cpu().numpy(),
                self.quats.cpu().numpy(),
            ]
            if self.features is not None:
                cols.append(self.features.cpu().numpy())
            data = np.concatenate(cols, axis=1).astype(np.float32)
        names = self.ply_attribute_names()
        rec = np.empty(n, dtype=[(a, "f4") for a in names])
        for i, a in enumerate(names):
            rec[a] = data[:, i]
        el = PlyElement.describe(rec, "vertex")
        with atomic_path(path) as tmp:
            PlyData([el]).write(tmp)

    @classmethod
    def load_ply(cls, path: str | Path) -> GaussianModel:
        """Read a 3DGS / Deformable-3DGS / TRASE PLY; SH degree from the f_rest count.

        Feature columns ``gaussian_feats_i`` (TRASE) or ``obj_dc_i`` (older TRASE) or
        ``feat_i`` are read when present. Every problem is a GaussianFileError naming the file.
        """
        from plyfile import PlyData

        path = Path(path)
        if not path.is_file():
            raise GaussianFileError(f"{path}: gaussian point cloud file not found")
        try:
            ply = PlyData.read(str(path))
            v = ply["vertex"]
        except Exception as exc:  # noqa: BLE001 - plyfile raises many kinds on corrupt input
            raise GaussianFileError(f"{path}: not a readable PLY file ({type(exc).__name__}: {exc})") from None
        names = [p.name for p in v.properties]
        required = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2",
                    "rot_0", "rot_1", "rot_2", "rot_3"]
        missing = [a for a in required if a not in names]
        if missing:
            raise GaussianFileError(f"{path}: not a gaussian PLY, missing attributes {', '.join(missing)}")

        def cols(prefix: str) -> list[str]:
            sel = [a for a in names if a.startswith(prefix) and a[len(prefix):].isdigit()]
            return sorted(sel, key=lambda a: int(a[len(prefix):]))

        try:
            col = lambda a: np.asarray(v[a], dtype=np.float32)
            n = len(col("x"))
            means = np.stack([col("x"), col("y"), col("z")], 1)
            dc = np.stack([col(f"f_dc_{i}") for i in range(3)], 1)
            rest_names = cols("f_rest_")
            if len(rest_names) % 3:
                raise GaussianFileError(f"{path}: {len(rest_names)} f_rest columns is not a multiple of 3")
            k = len(rest_names) // 3 + 1
            if round(math.sqrt(k)) ** 2 != k:
                raise GaussianFileError(f"{path}: {len(rest_names)} f_rest columns match no SH degree")
            rest = np.stack([col(a) for a in rest_names], 1) if rest_names else np.zeros((n, 0), np.float32)
            rest = rest.reshape(n, 3, k - 1).transpose(0, 2, 1)
            opac = col("opacity")
            scales = np.stack([col(f"scale_{i}") for i in range(3)], 1)
            rots = np.stack([col(f"rot_{i}") for i in range(4)], 1)
            feats = None
            for prefix in ("gaussian_feats_", "obj_dc_", "feat_"):
                fn = cols(prefix)
                if fn:
                    feats = torch.from_numpy(np.stack([col(a) for a in fn], 1))
                    break
        except GaussianFileError:
            raise
        except Exception as exc:  # noqa: BLE001 - numpy/plyfile errors on malformed columns
            raise GaussianFileError(f"{path}: malformed gaussian attributes ({type(exc).__name__}: {exc})") from None
        for label, arr in (("x/y/z", means), ("opacity", opac), ("scale", scales), ("rot", rots)):
            if not np.isfinite(arr).all():
                raise GaussianFileError(f"{path}: non-finite values in {label}")
        sh = np.concatenate([dc[:, None, :], rest], axis=1)
        t = torch.from_numpy
        return cls(t(means), t(scales), t(rots), t(opac), t(np.ascontiguousarray(sh)), feats)

    # -- densification (keeps an Adam optimizer consistent) ------------------------------
    def _swap(self, optimizer: torch.optim.Optimizer | None, make_new, state_fn) -> None:
        """Replace every per-gaussian parameter by make_new(name, old) and its Adam moments
        by state_fn(name, old_moment); the optimizer's param groups then hold the new ones."""
        old_params = self.param_tensors()
        new_params = {name: nn.Parameter(make_new(name, p.data).contiguous()) for name, p in old_params.items()}
        if optimizer is not None:
            by_id = {id(p): name for name, p in old_params.items()}
            for group in optimizer.param_groups:
                for j, p in enumerate(group["params"]):
                    name = by_id.get(id(p))
                    if name is None:
                        continue
                    newp = new_params[name]
                    st = optimizer.state.pop(p, None)
                    if st:
                        for key in ("exp_avg", "exp_avg_sq", "max_exp_avg_sq"):
                            if key in st and torch.is_tensor(st[key]) and st[key].shape == p.shape:
                                st[key] = state_fn(name, st[key]).contiguous()
                        optimizer.state[newp] = st
                    group["params"][j] = newp
        for name, p in new_params.items():
            setattr(self, name, p)

    @torch.no_grad()
    def prune(self, keep: torch.Tensor, optimizer: torch.optim.Optimizer | None = None) -> None:
        """Keep only gaussians where keep [N] bool is True."""
        keep = keep.to(torch.bool)
        self._swap(optimizer, lambda _, t: t[keep], lambda _, m: m[keep])

    @torch.no_grad()
    def append(self, new: dict[str, torch.Tensor], optimizer: torch.optim.Optimizer | None = None) -> None:
        """Add gaussians given raw parameter values for every per-gaussian parameter; their
        Adam moments start at zero."""
        missing = set(self.param_tensors()) - set(new)
        if missing:
            raise ValueError(f"append: missing values for {sorted(missing)}")
        self._swap(
            optimizer,
            lambda name, t: torch.cat([t, new[name].to(t.dtype)], 0),
            lambda name, m: torch.cat([m, torch.zeros_like(new[name], dtype=m.dtype)], 0),
        )

    @torch.no_grad()
    def clone_gaussians(self, mask: torch.Tensor, optimizer: torch.optim.Optimizer | None = None) -> None:
        """3DGS clone: duplicate the selected gaussians unchanged (appended at the end)."""
        mask = mask.to(torch.bool)
        self.append({name: p.data[mask].clone() for name, p in self.param_tensors().items()}, optimizer)

    @torch.no_grad()
    def split_gaussians(
        self,
        mask: torch.Tensor,
        optimizer: torch.optim.Optimizer | None = None,
        n: int = 2,
        generator: torch.Generator | None = None,
    ) -> None:
        """3DGS split: replace each selected gaussian by n samples drawn from it, with scales
        divided by 0.8 * n; the originals are removed."""
        mask = mask.to(torch.bool)
        m = int(mask.sum())
        if m == 0:
            return
        scales = self.scales[mask].repeat(n, 1)  # [n*m, 3]
        rot = quat_to_rotmat(self.rotations[mask]).repeat(n, 1, 1)  # [n*m, 3, 3]
        # drawn on the CPU generator, then moved: the same samples on every device
        samples = torch.randn(scales.shape, generator=generator, dtype=scales.dtype).to(scales.device) * scales
        new = {name: p.data[mask].repeat((n,) + (1,) * (p.dim() - 1)) for name, p in self.param_tensors().items()}
        new["means"] = (rot @ samples[:, :, None])[:, :, 0] + self.means.data[mask].repeat(n, 1)
        new["log_scales"] = torch.log(scales / (0.8 * n))
        old_n = self.num_gaussians
        self.append(new, optimizer)
        keep = torch.ones(self.num_gaussians, dtype=torch.bool, device=self.means.device)
        keep[:old_n][mask] = False
        self.prune(keep, optimizer)

    @torch.no_grad()
    def reset_opacity(self, optimizer: torch.optim.Optimizer | None = None, ceiling: float = 0.01) -> None:
        """3DGS opacity reset: opacity = min(opacity, ceiling), its Adam moments zeroed."""
        new_logits = inverse_sigmoid(torch.minimum(self.opacities, torch.full_like(self.opacities, ceiling)))
        self._swap(
            optimizer,
            lambda name, t: new_logits.clone() if name == "opacity_logits" else t,
            lambda name, m: torch.zeros_like(m) if name == "opacity_logits" else m,
        )

    def copy(self) -> GaussianModel:
        """A detached deep copy (no optimizer ties)."""
        with torch.no_grad():
            g = GaussianModel(
                self.means, self.log_scales, self.quats, self.opacity_logits, self.sh,
                self.features, active_sh_degree=self.active_sh_degree,
            )
        return g
