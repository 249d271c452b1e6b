"""scripts/measure_motion.py: how many gaussians move, per checkpoint of a model folder."""

import runpy
from pathlib import Path

import torch

from trase.checkpoint import save_model
from trase.deformation import DeformMLP
from trase.gaussians import GaussianModel

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "measure_motion.py"


def test_counts_the_gaussians_the_network_moves_at_each_checkpoint(tmp_path, capsys):
    g = GaussianModel.from_points(torch.linspace(-1, 1, 30)[:, None].repeat(1, 3).numpy(), None, sh_degree=0)
    net = DeformMLP.preset("small")
    net.zero_heads()  # the identity: nothing moves
    save_model(tmp_path / "m", g, net, 100)
    main = runpy.run_path(str(SCRIPT))["main"]
    assert main([str(tmp_path / "m"), "--times", "5", "--above", "0.0", "1e9"]) == 0
    row = capsys.readouterr().out.strip().splitlines()[-1]
    assert row.endswith("| 100 | 30 | 0.000 | 0 | 0")
    torch.manual_seed(0)
    with torch.no_grad():  # a network that moves every gaussian with time
        for p in net.parameters():
            p.add_(0.1 * torch.randn_like(p))
    save_model(tmp_path / "m", g, net, 200)
    assert main([str(tmp_path / "m"), "--times", "5", "--above", "0.0", "1e9"]) == 0
    rows = capsys.readouterr().out.strip().splitlines()
    assert rows[-1].split(" | ")[1:3] == ["200", "30"] and rows[-1].endswith("| 30 | 0")
    assert main([str(tmp_path / "empty")]) == 2


def test_training_view_psnr_of_the_scene_the_model_was_trained_on(tmp_path):
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "trase"))
    from recon_scene import write_scene

    views, _, g, deform = write_scene(tmp_path / "images", num=4, size=24)
    script = runpy.run_path(str(SCRIPT))
    ps, ts = script["view_psnrs"](g, deform, views)  # the ground truth against its own 8-bit images
    assert ps.shape == (4,) and (ps > 35).all()
    assert ts.tolist() == [v.camera.time for v in views]
    assert script["main"]([str(tmp_path / "a"), str(tmp_path / "b"), "--scene", str(tmp_path)]) == 2
