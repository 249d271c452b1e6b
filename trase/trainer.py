"""The reconstruction's trainer: everything its loop changes from one iteration to the next, the
optimizers, and the trainer-state file beside each checkpoint, so that a resumed run continues
bit for bit (the loop: ``trase.reconstruct``)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import torch

from trase.checkpoint import CheckpointError, load_model, save_model
from trase.convergence import Plateau
from trase.deformation import DeformMLP
from trase.densify import DensifyStrategy
from trase.gaussians import GaussianModel
from trase.io import atomic_torch_save, read_torch
from trase.losses import psnr_of_mse
from trase.reconstruction_config import ReconstructionConfig
from trase.resolution_schedule import ScaledViews


def make_optimizers(g: GaussianModel, deform: DeformMLP, cfg: ReconstructionConfig):
    """Adam over the gaussians' parameters (a group each, the public trainer's rates) and over
    the network (None for a motionless capture); the schedules set the rates each step."""
    groups = [
        {"params": [g.means], "lr": cfg.position_lr_init * cfg.spatial_lr_scale, "name": "means"},
        {"params": [g.sh_dc], "lr": cfg.feature_lr, "name": "sh_dc"},
        {"params": [g.sh_rest], "lr": cfg.feature_lr / 20.0, "name": "sh_rest"},
        {"params": [g.opacity_logits], "lr": cfg.opacity_lr, "name": "opacity_logits"},
        {"params": [g.log_scales], "lr": cfg.scaling_lr, "name": "log_scales"},
        {"params": [g.quats], "lr": cfg.rotation_lr, "name": "quats"},
    ]
    opt_g = torch.optim.Adam(groups, lr=0.0, eps=1e-15, fused=True)
    if deform is None:  # a motionless capture: plain 3DGS
        return opt_g, None
    opt_d = torch.optim.Adam(
        [{"params": list(deform.parameters()), "lr": cfg.position_lr_init * cfg.spatial_lr_scale, "name": "deform"}],
        lr=0.0, eps=1e-15, fused=True,
    )
    return opt_g, opt_d


def state_path(out_dir: Path, iteration: int) -> Path:
    """The sidecar trainer state of the checkpoint at ``iteration``."""
    return out_dir / "trainer_state" / f"iteration_{iteration}.pt"


# what a trainer-state file must hold to resume (beside "iteration")
STATE_KEYS = ("active_sh_degree", "opt_g", "opt_d", *DensifyStrategy.STATE_KEYS, "rng", "view_stack",
               "ema_loss", "ema_psnr")


@dataclasses.dataclass
class Trainer:
    """Everything the loop changes from one iteration to the next: what a checkpoint saves and
    a resumed run restores, so a resumed run continues bit for bit."""

    gaussians: GaussianModel
    deform: DeformMLP | None  # None: a motionless capture, trained as plain 3DGS
    opt_g: torch.optim.Optimizer  # the gaussians' parameters, one group each (make_optimizers)
    opt_d: torch.optim.Optimizer | None  # the deformation network's
    strategy: DensifyStrategy
    gen: torch.Generator  # the run's draws: view order, time noise, splits
    view_stack: list[int]  # views left in the current random pass (popped from the end)
    ema_loss: float = 0.0  # smoothed loss and training PSNR (dB), for the log
    ema_psnr: float = 0.0
    # (iteration, loss [], squared error []) of the steps not yet folded into the smoothed
    # values: read from the device only when the log or a checkpoint needs them (``fold``)
    pending: list = dataclasses.field(default_factory=list)
    # static gaussians (trase.static_gaussians; None until the first check): [N] bool and
    # their frozen offsets [N, 10]
    static: torch.Tensor | None = None
    frozen: torch.Tensor | None = None
    plateau: Plateau | None = None  # the stopping checks (stop_interval > 0)
    scaled: ScaledViews | None = None  # the views at each iteration's size (a resolution schedule)

    def deformation(self):
        """What renders this step: the network, or the network for the moving gaussians only."""
        if self.deform is None or self.static is None:  # static rows not measured yet
            return self.deform
        from trase.static_gaussians import PartlyStaticDeformation

        return PartlyStaticDeformation(self.deform, self.static, self.frozen)

    @property
    def n_static(self) -> int:
        return 0 if self.static is None else int(self.static.sum())

    def fold(self) -> None:
        """The pending steps' loss and PSNR folded into ema_loss / ema_psnr, in order: one
        transfer from the device for all of them."""
        if not self.pending:
            return
        values = torch.stack([torch.stack([loss.double(), mse]) for _, loss, mse in self.pending]).cpu().tolist()
        for (it, _, _), (lv, mse) in zip(self.pending, values):
            pv = psnr_of_mse(mse)
            self.ema_loss = lv if it == 1 else 0.4 * lv + 0.6 * self.ema_loss
            self.ema_psnr = pv if it == 1 else 0.4 * pv + 0.6 * self.ema_psnr
        self.pending.clear()

    def state_dict(self, it: int) -> dict:
        """The trainer-state file's contents (keys and order as ever: old files still load)."""
        self.fold()
        return {
            "iteration": it,
            "active_sh_degree": self.gaussians.active_sh_degree,
            "opt_g": self.opt_g.state_dict(),
            "opt_d": None if self.opt_d is None else self.opt_d.state_dict(),
            **self.strategy.state_dict(),
            "rng": self.gen.get_state(),
            "view_stack": torch.tensor(self.view_stack, dtype=torch.int64),
            "ema_loss": self.ema_loss, "ema_psnr": self.ema_psnr,
            **({} if self.static is None else {"static": self.static.cpu(), "frozen": self.frozen.cpu()}),
            **({} if self.plateau is None else {"plateau": self.plateau.state()}),
        }


def new_trainer(points, point_colors, cfg: ReconstructionConfig, dev, strategy: DensifyStrategy,
                 gen: torch.Generator, static: bool = False) -> Trainer:
    """A run from the point cloud: gaussians and network initialised on the CPU (alike on
    every device), then moved; ``static``: no network (plain 3DGS)."""
    gaussians = GaussianModel.from_points(points, point_colors, sh_degree=cfg.sh_degree)
    deform = None
    if not static:
        deform = DeformMLP.preset(cfg.deform_preset, scale_rule=cfg.deform_scale_rule)
        if cfg.deform_zero_init:
            deform.zero_heads()
        deform = deform.to(dev)
    gaussians = gaussians.to(dev)
    opt_g, opt_d = make_optimizers(gaussians, deform, cfg)
    strategy.initialize_state(gaussians.num_gaussians, dev)
    plateau = Plateau(cfg.stop_rule()) if cfg.stop_interval > 0 else None
    return Trainer(gaussians, deform, opt_g, opt_d, strategy, gen, [], plateau=plateau)


def resumed_trainer(out_dir: Path, start: int, cfg: ReconstructionConfig, dev,
                     strategy: DensifyStrategy, gen: torch.Generator, static: bool = False) -> Trainer:
    """The run saved at iteration ``start``: its model and its trainer state (CheckpointError
    when either is missing, unreadable or incomplete)."""
    gaussians, deform = load_model(out_dir, start)
    from trase.static_gaussians import PartlyStaticDeformation

    if isinstance(deform, PartlyStaticDeformation):
        deform = deform.net  # its static rows come back with the trainer state
    if deform is None and not static:
        raise CheckpointError(f"{out_dir}: checkpoint {start} has no deformation network to resume")
    if deform is not None and static:
        raise CheckpointError(f"{out_dir}: checkpoint {start} has a deformation network, but every view is at one "
                              "time (a motionless capture trains none): remove the folder to start over")
    gaussians = gaussians.to(dev)
    sp = state_path(out_dir, start)
    if not sp.is_file():
        raise CheckpointError(f"{sp}: trainer state for iteration {start} is missing; cannot resume")
    state = read_torch(sp, CheckpointError, "unreadable trainer state")
    lost = [k for k in STATE_KEYS if not isinstance(state, dict) or k not in state]
    if lost:
        raise CheckpointError(f"{sp}: trainer state lacks {', '.join(lost)}")
    try:
        strategy.load_state_dict(state, gaussians.num_gaussians, dev)
    except ValueError as exc:
        raise CheckpointError(f"{sp}: {exc}") from None
    gaussians.active_sh_degree = int(state["active_sh_degree"])
    if deform is not None:
        deform = deform.to(dev)
        deform.scale_rule = cfg.deform_scale_rule  # the run's rule (older checkpoints do not record it)
        deform.train()
    opt_g, opt_d = make_optimizers(gaussians, deform, cfg)
    opt_g.load_state_dict(state["opt_g"])
    if opt_d is not None:
        opt_d.load_state_dict(state["opt_d"])
    gen.set_state(state["rng"])
    tr = Trainer(gaussians, deform, opt_g, opt_d, strategy, gen, [int(i) for i in state["view_stack"]],
                  float(state["ema_loss"]), float(state["ema_psnr"]))
    if "static" in state:
        tr.static, tr.frozen = state["static"].to(dev), state["frozen"].to(dev)
    if cfg.stop_interval > 0:
        tr.plateau = Plateau(cfg.stop_rule())
        tr.plateau.restore(state.get("plateau"))
    return tr


def save_trainer(tr: Trainer, out_dir: Path, it: int, cfg: ReconstructionConfig) -> None:
    """Trainer state, then the model in the public layout (its PLY last: marks it complete)."""
    atomic_torch_save(tr.state_dict(it), state_path(out_dir, it))
    save_model(out_dir, tr.gaussians, tr.deformation(), it, white_background=cfg.white_background)


__all__ = ["STATE_KEYS", "Trainer", "make_optimizers", "new_trainer", "resumed_trainer", "save_trainer", "state_path"]
