"""Model checkpoints in the public Deformable-3DGS / TRASE layout, both ways.

    <model_dir>/point_cloud/iteration_N/point_cloud.ply   canonical gaussians (3DGS PLY)
    <model_dir>/deform/iteration_N/deform.pth             DeformNetwork state dict

A model trained with the public GPU code can be loaded here, and one trained here loads in
the public code. Deformation networks are rebuilt from the state dict's shapes (paper size
or the small CPU preset). The synthetic scenes' ground truth (geometry.npz) loads into the
same types with a TabulatedDeformation.
"""

from __future__ import annotations

import io
import json
import re
import zipfile
from pathlib import Path

import numpy as np
import torch

from trase.deformation import DeformMLP, TabulatedDeformation, infer_mlp_config
from trase.gaussians import GaussianFileError, GaussianModel, rgb_to_sh_dc
from trase.io import atomic_torch_save, atomic_write_bytes, read_torch


class CheckpointError(ValueError):
    """A missing or corrupt checkpoint; the message names the file and the problem."""

    user_facing = True


_ITER_RE = re.compile(r"^iteration_(\d+)$")


def available_iterations(model_dir: str | Path) -> list[int]:
    """Iterations with a point cloud saved under model_dir, ascending."""
    pc = Path(model_dir) / "point_cloud"
    if not pc.is_dir():
        return []
    its = []
    for d in pc.iterdir():
        m = _ITER_RE.match(d.name)
        if m and (d / "point_cloud.ply").is_file():
            its.append(int(m.group(1)))
    return sorted(its)


def ply_path(model_dir: str | Path, iteration: int) -> Path:
    return Path(model_dir) / "point_cloud" / f"iteration_{iteration}" / "point_cloud.ply"


def deform_path(model_dir: str | Path, iteration: int) -> Path:
    return Path(model_dir) / "deform" / f"iteration_{iteration}" / "deform.pth"


def deform_options_path(model_dir: str | Path, iteration: int) -> Path:
    """The network's options the weights do not say (its scale rule): this project's addition
    to the layout, beside deform.pth; a folder without it is the public code's (rule mirror), or
    this project's from before the rule was recorded (rule clamp: ``load_deformation``)."""
    return Path(model_dir) / "deform" / f"iteration_{iteration}" / "deform_options.json"


def static_rows_path(model_dir: str | Path, iteration: int) -> Path:
    """The static gaussians of a network trained with them (``trase.static_gaussians``): which
    rows skip the network and their frozen offsets. This project's addition beside deform.pth;
    the public code, which reads deform.pth only, would run the network for every row."""
    return Path(model_dir) / "deform" / f"iteration_{iteration}" / "static_rows.npz"


def deform_table_path(model_dir: str | Path, iteration: int) -> Path:
    """Tabulated motion (an edited composition baked per time): this project's addition to
    the layout; the public code reads only deform.pth."""
    return Path(model_dir) / "deform" / f"iteration_{iteration}" / "deform_table.npz"


def write_cfg_args(model_dir: str | Path, sh_degree: int, blender: bool = False, source_path: str = "",
                   white_background: bool = False) -> None:
    """The ``cfg_args`` file the public scripts (render.py, TRASE's train/gui) read from a model
    folder: a printed argparse Namespace. Its sh_degree must match the PLY's f_rest count
    (their loader asserts it) and is_blender picks the deform network variant."""
    model_dir = Path(model_dir)
    ns = (
        f"Namespace(sh_degree={int(sh_degree)}, source_path={source_path!r}, "
        f"model_path={str(model_dir.resolve())!r}, images='images', resolution=-1, "
        f"white_background={bool(white_background)}, data_device='cuda', eval=True, "
        f"load2gpu_on_the_fly=False, is_blender={bool(blender)}, is_6dof=False)"
    )
    atomic_write_bytes(model_dir / "cfg_args", ns.encode())


def save_model(model_dir: str | Path, gaussians: GaussianModel, deformation, iteration: int,
               source_path: str = "", white_background: bool = False) -> None:
    """Write both files of ``iteration`` atomically; the deform file is written first so a
    point cloud (which marks the iteration as present) never exists without it. A
    ``cfg_args`` beside them lets the public scripts open the folder (they build the paper
    size network, so only ``DeformMLP.preset("paper")`` models load there).

    ``deformation`` is a DeformMLP (deform.pth, the public format), a TabulatedDeformation
    (deform_table.npz, read by ``load_model`` here only) or None for a static model.
    """
    from trase.static_gaussians import PartlyStaticDeformation

    if isinstance(deformation, PartlyStaticDeformation):
        buf = io.BytesIO()
        np.savez_compressed(buf, static=deformation.static.cpu().numpy(), frozen=deformation.frozen.cpu().numpy())
        atomic_write_bytes(static_rows_path(model_dir, iteration), buf.getvalue())
        deformation = deformation.net
    if isinstance(deformation, TabulatedDeformation):
        buf = io.BytesIO()
        np.savez_compressed(buf, **{k: getattr(deformation, k).cpu().numpy() for k in ("times", "d_xyz", "d_rot", "d_scale")})
        atomic_write_bytes(deform_table_path(model_dir, iteration), buf.getvalue())
    elif deformation is not None:
        if not isinstance(deformation, DeformMLP):
            raise TypeError(f"save_model: can only save a DeformMLP or a TabulatedDeformation, got {type(deformation).__name__}")
        sd = {k: v.detach().cpu().clone() for k, v in deformation.state_dict().items()}
        atomic_write_bytes(deform_options_path(model_dir, iteration),
                           json.dumps({"scale_rule": deformation.scale_rule}).encode())
        atomic_torch_save(sd, deform_path(model_dir, iteration))
    write_cfg_args(model_dir, gaussians.max_sh_degree, bool(getattr(deformation, "blender", False)),
                   source_path, white_background)
    gaussians.save_ply(ply_path(model_dir, iteration))


def load_deformation(path: Path) -> DeformMLP:
    """A DeformMLP from a public-layout deform.pth (architecture inferred from its shapes)."""
    if not path.is_file():
        raise CheckpointError(f"{path}: deformation weights not found")
    sd = read_torch(path, CheckpointError)
    if not isinstance(sd, dict) or not all(torch.is_tensor(v) for v in sd.values()):
        raise CheckpointError(f"{path}: expected a state dict of tensors, got {type(sd).__name__}")
    options = path.parent / "deform_options.json"
    # without the file: the public code's rule, unless this project's trainer wrote the folder
    # (its trainer_state/, which the public code never writes) before the rule was recorded,
    # when every preset trained with the floor
    rule = "clamp" if (path.parent.parent.parent / "trainer_state").is_dir() else "mirror"
    if options.is_file():
        try:
            rule = json.loads(options.read_text())["scale_rule"]
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise CheckpointError(f"{options}: unreadable ({type(exc).__name__}: {exc})") from None
    try:
        net = DeformMLP(**infer_mlp_config(sd), scale_rule=rule)
        net.load_state_dict(sd, strict=True)
    except (ValueError, RuntimeError, KeyError) as exc:
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise CheckpointError(f"{path}: {msg}") from None
    net.eval()
    return net


def load_deformation_table(path: Path) -> TabulatedDeformation:
    """A TabulatedDeformation from a ``save_model`` deform_table.npz."""
    try:
        with np.load(path, allow_pickle=False) as z:
            d = {k: z[k] for k in z.files}
        return TabulatedDeformation(d["times"], d["d_xyz"], d["d_rot"], d["d_scale"])
    except (OSError, ValueError, KeyError, zipfile.BadZipFile, EOFError) as exc:
        raise CheckpointError(f"{path}: not a readable motion table ({type(exc).__name__}: {exc})") from None


def load_model(model_dir: str | Path, iteration: int | None = None) -> tuple[GaussianModel, DeformMLP | None]:
    """(gaussians, deformation) saved at ``iteration`` (the latest when None).

    The deformation is None when the model has no deform folder at all (a static 3DGS
    model); a deform folder without the requested iteration is an error.
    """
    model_dir = Path(model_dir)
    if not model_dir.is_dir():
        raise CheckpointError(f"{model_dir}: model directory not found")
    its = available_iterations(model_dir)
    if iteration is None:
        if not its:
            raise CheckpointError(f"{model_dir}: no point_cloud/iteration_N/point_cloud.ply checkpoint found")
        iteration = its[-1]
    ply = ply_path(model_dir, iteration)
    if not ply.is_file():
        have = ", ".join(map(str, its)) or "none"
        raise CheckpointError(f"{ply}: no checkpoint for iteration {iteration} (available: {have})")
    try:
        gaussians = GaussianModel.load_ply(ply)
    except GaussianFileError as exc:
        raise CheckpointError(str(exc)) from None
    dpath = deform_path(model_dir, iteration)
    if not (model_dir / "deform").exists():
        return gaussians, None
    table = deform_table_path(model_dir, iteration)
    if table.is_file() and not dpath.is_file():
        deformation = load_deformation_table(table)
        if deformation.num_gaussians != gaussians.num_gaussians:
            raise CheckpointError(f"{table}: motion of {deformation.num_gaussians} gaussians for "
                                  f"{gaussians.num_gaussians} in the point cloud")
        return gaussians, deformation
    net = load_deformation(dpath)
    rows = static_rows_path(model_dir, iteration)
    if not rows.is_file():
        return gaussians, net
    from trase.static_gaussians import PartlyStaticDeformation

    try:
        with np.load(rows, allow_pickle=False) as z:
            static, frozen = torch.from_numpy(z["static"]), torch.from_numpy(z["frozen"])
        deformation = PartlyStaticDeformation(net, static, frozen)
    except (OSError, ValueError, KeyError, zipfile.BadZipFile, EOFError) as exc:
        raise CheckpointError(f"{rows}: not readable static rows ({type(exc).__name__}: {exc})") from None
    if deformation.num_gaussians != gaussians.num_gaussians:
        raise CheckpointError(f"{rows}: static rows of {deformation.num_gaussians} gaussians for "
                              f"{gaussians.num_gaussians} in the point cloud")
    return gaussians, deformation


# arrays of a tabulated geometry file: gaussians at the first time, per-time offsets [T, N, *]
TABULATED_KEYS = ("means", "log_scales", "quats", "opacity_logits", "colors", "object_ids", "times",
                  "d_xyz", "d_rot", "d_scale")


def save_tabulated_geometry(npz_path: str | Path, arrays: dict[str, np.ndarray]) -> None:
    """Write gaussians with tabulated motion (``TABULATED_KEYS``; the synthetic scenes'
    ground truth) as one compressed .npz, the file ``load_tabulated_geometry`` reads."""
    missing = [k for k in TABULATED_KEYS if k not in arrays]
    if missing:
        raise ValueError(f"tabulated geometry lacks arrays {', '.join(missing)}")
    np.savez_compressed(npz_path, **{k: arrays[k] for k in TABULATED_KEYS})


def load_tabulated_geometry(npz_path: str | Path) -> tuple[GaussianModel, TabulatedDeformation, np.ndarray]:
    """Gaussians, their tabulated motion and object ids [N] from a ``save_tabulated_geometry`` file."""
    path = Path(npz_path)
    if not path.is_file():
        raise CheckpointError(f"{path}: synthetic geometry file not found")
    try:
        with np.load(path, allow_pickle=False) as z:
            d = {k: z[k] for k in z.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        raise CheckpointError(f"{path}: not a readable .npz file ({type(exc).__name__}: {exc})") from None
    keys = TABULATED_KEYS
    missing = [k for k in keys if k not in d]
    if missing:
        raise CheckpointError(f"{path}: missing arrays {', '.join(missing)}")
    n = d["means"].shape[0] if d["means"].ndim == 2 else -1
    t = d["times"].reshape(-1).shape[0]
    want = {
        "means": (n, 3), "log_scales": (n, 3), "quats": (n, 4), "opacity_logits": (n,), "colors": (n, 3),
        "object_ids": (n,), "d_xyz": (t, n, 3), "d_rot": (t, n, 4), "d_scale": (t, n, 3),
    }
    for k, shape in want.items():
        if n < 0 or tuple(d[k].shape) != shape:
            raise CheckpointError(f"{path}: array {k} has shape {tuple(d[k].shape)}, expected {shape}")
    for k in keys:
        if k != "object_ids" and not np.isfinite(d[k]).all():
            raise CheckpointError(f"{path}: array {k} has non-finite values")
    f = lambda a: torch.as_tensor(np.asarray(a, dtype=np.float32))
    sh = rgb_to_sh_dc(np.clip(d["colors"].astype(np.float64), 0.0, 1.0))[:, None, :]
    g = GaussianModel(f(d["means"]), f(d["log_scales"]), f(d["quats"]), f(d["opacity_logits"]), f(sh))
    try:
        deform = TabulatedDeformation(d["times"], d["d_xyz"], d["d_rot"], d["d_scale"])
    except ValueError as exc:
        raise CheckpointError(f"{path}: {exc}") from None
    return g, deform, np.asarray(d["object_ids"]).astype(np.int32)


FLOAT_BYTES = 4  # every stored parameter is float32


def model_storage(gaussians: GaussianModel, deformation, feature_dim: int) -> dict:
    """Bytes of the model itself, as the paper reports storage: the gaussians' parameters
    (means, scales, rotations, opacities, SH colour), their ``feature_dim``-d features and the
    deformation's parameters, float32; no optimiser state, checkpoints or caches.
    ``total_mib`` is in MiB (2^20 bytes): the paper's feature-dimension table (16 -> 128 dims:
    +80 "MB" on NeRF-DS's 186k gaussians) matches 2^20, not 10^6."""
    n = int(gaussians.num_gaussians)
    g = gaussians
    g_bytes = sum(int(t.numel()) for t in (g.means, g.log_scales, g.quats, g.opacity_logits, g.sh_dc, g.sh_rest)) \
        * FLOAT_BYTES
    f_bytes = n * int(feature_dim) * FLOAT_BYTES
    d_bytes = 0 if deformation is None else sum(int(p.numel()) for p in deformation.state_dict().values()) * FLOAT_BYTES
    total = g_bytes + f_bytes + d_bytes
    return {"gaussians_bytes": g_bytes, "features_bytes": f_bytes, "deformation_bytes": d_bytes,
            "total_bytes": total, "total_mib": total / 2**20}
