import numpy as np
import pytest
import torch

from trase.camera import Camera, intrinsics, look_at
from trase.checkpoint import CheckpointError, load_model, load_tabulated_geometry, save_model
from trase.deformation import DeformMLP, deformed
from trase.gaussians import GaussianModel
from trase.render import rasterize


def _model(n=60, seed=0):
    g = torch.Generator().manual_seed(seed)
    gs = GaussianModel(torch.rand(n, 3, generator=g) - 0.5, torch.full((n, 3), -2.5), torch.randn(n, 4, generator=g),
                       torch.randn(n, generator=g), torch.randn(n, 16, 3, generator=g) * 0.3,
                       torch.randn(n, 8, generator=g))
    torch.manual_seed(seed)
    return gs, DeformMLP.preset("small")


def _render(g, d, t=0.4):
    cam = Camera(K=intrinsics(30, 30, 16, 12), w2c=look_at(np.array([0, -3.0, 0.5]), np.zeros(3)),
                 width=32, height=24, time=t)
    with torch.no_grad():
        m, q, s = deformed(g, d, t)
        return rasterize(m, q, s, g.opacities, cam, colors=g.sh, sh_degree=3, features=g.features, backend="torch")


def test_export_import_renders_identically(tmp_path):
    g, d = _model()
    save_model(tmp_path, g, d, 7)
    g2, d2 = load_model(tmp_path)
    a, b = _render(g, d), _render(g2, d2)
    assert torch.equal(a.color, b.color) and torch.equal(a.features, b.features)
    assert torch.equal(a.depth, b.depth) and torch.equal(a.alpha, b.alpha)
    assert a.alpha.max() > 0.1  # the comparison is not between two empty images
    # public layout
    assert (tmp_path / "point_cloud/iteration_7/point_cloud.ply").is_file()
    sd = torch.load(tmp_path / "deform/iteration_7/deform.pth", weights_only=True)
    assert set(sd) == set(d.state_dict())
    from argparse import Namespace  # noqa: F401  (the public scripts eval cfg_args)

    ns = eval((tmp_path / "cfg_args").read_text())
    assert ns.sh_degree == 3 and ns.is_blender is False


def test_latest_and_explicit_iteration(tmp_path):
    g1, d1 = _model(seed=1)
    g2, d2 = _model(seed=2)
    save_model(tmp_path, g1, d1, 100)
    save_model(tmp_path, g2, d2, 2000)
    g, _ = load_model(tmp_path)
    assert torch.equal(g.means, g2.means)
    g, _ = load_model(tmp_path, 100)
    assert torch.equal(g.means, g1.means)
    with pytest.raises(CheckpointError, match="iteration 5 .*available: 100, 2000"):
        load_model(tmp_path, 5)


def test_public_paper_size_state_dict_loads(tmp_path):
    # what Deformable-3DGS writes: torch.save(DeformNetwork().state_dict()) with its names
    g, _ = _model()
    paper = DeformMLP.preset("paper")
    g.save_ply(tmp_path / "point_cloud/iteration_40000/point_cloud.ply")
    (tmp_path / "deform/iteration_40000").mkdir(parents=True)
    torch.save(paper.state_dict(), tmp_path / "deform/iteration_40000/deform.pth")
    _, d = load_model(tmp_path)
    assert d.config() == paper.config()
    x = torch.randn(5, 3)
    assert torch.equal(d(x, 0.5)[0], paper(x, 0.5)[0])


def test_corrupt_and_missing_checkpoints(tmp_path):
    with pytest.raises(CheckpointError, match="not found"):
        load_model(tmp_path / "nope")
    with pytest.raises(CheckpointError, match="no point_cloud"):
        load_model(tmp_path)
    g, d = _model()
    save_model(tmp_path, g, d, 1)
    dp = tmp_path / "deform/iteration_1/deform.pth"
    dp.write_bytes(b"garbage")
    with pytest.raises(CheckpointError, match="deform.pth.*not a readable"):
        load_model(tmp_path)
    torch.save({"linear.0.weight": torch.zeros(3, 3)}, dp)
    with pytest.raises(CheckpointError, match="deform.pth"):
        load_model(tmp_path)
    dp.unlink()
    with pytest.raises(CheckpointError, match="deform.pth: deformation weights not found"):
        load_model(tmp_path)
    pp = tmp_path / "point_cloud/iteration_1/point_cloud.ply"
    pp.write_bytes(pp.read_bytes()[:300])  # truncated
    with pytest.raises(CheckpointError, match="point_cloud.ply"):
        load_model(tmp_path)
    assert CheckpointError.user_facing


def _geometry(n=5, T=3):
    rng = np.random.default_rng(0)
    return {
        "means": rng.normal(size=(n, 3)), "log_scales": np.full((n, 3), -2.0), "quats": np.tile([1.0, 0, 0, 0], (n, 1)),
        "opacity_logits": np.zeros(n), "colors": rng.uniform(size=(n, 3)), "object_ids": np.arange(n, dtype=np.int32),
        "times": np.linspace(0, 1, T), "d_xyz": rng.normal(size=(T, n, 3)), "d_rot": np.zeros((T, n, 4)),
        "d_scale": np.zeros((T, n, 3)),
    }


def test_load_tabulated_geometry(tmp_path):
    geo = _geometry()
    np.savez(tmp_path / "geometry.npz", **geo)
    g, d, ids = load_tabulated_geometry(tmp_path / "geometry.npz")
    assert torch.allclose(g.colors_dc, torch.as_tensor(geo["colors"], dtype=torch.float32), atol=1e-6)
    assert ids.dtype == np.int32 and list(ids) == list(range(5))
    m, _, _ = deformed(g, d, 0.5)
    assert torch.allclose(m, torch.as_tensor(geo["means"] + geo["d_xyz"][1], dtype=torch.float32), atol=1e-6)


def test_bad_synthetic_geometry(tmp_path):
    geo = _geometry()
    del geo["d_rot"]
    np.savez(tmp_path / "a.npz", **geo)
    with pytest.raises(CheckpointError, match="a.npz: missing arrays d_rot"):
        load_tabulated_geometry(tmp_path / "a.npz")
    geo = _geometry()
    geo["d_xyz"] = geo["d_xyz"][:, :2]
    np.savez(tmp_path / "b.npz", **geo)
    with pytest.raises(CheckpointError, match="b.npz: array d_xyz has shape"):
        load_tabulated_geometry(tmp_path / "b.npz")
    (tmp_path / "c.npz").write_bytes(b"not a zip")
    with pytest.raises(CheckpointError, match="c.npz: not a readable"):
        load_tabulated_geometry(tmp_path / "c.npz")
    with pytest.raises(CheckpointError, match="not found"):
        load_tabulated_geometry(tmp_path / "d.npz")


def test_tabulated_geometry_writer_checks_its_arrays(tmp_path):
    from trase.checkpoint import save_tabulated_geometry

    with pytest.raises(ValueError, match="lacks arrays means"):
        save_tabulated_geometry(tmp_path / "g.npz", {})


def test_scale_rule_is_saved_beside_the_weights(tmp_path):
    g, d = _model()
    d.scale_rule = "clamp"
    save_model(tmp_path / "clamp", g, d, 3)
    assert load_model(tmp_path / "clamp")[1].scale_rule == "clamp"
    # a folder without the options file is the public code's: rule mirror
    save_model(tmp_path / "public", g, DeformMLP.preset("small"), 3)
    (tmp_path / "public/deform/iteration_3/deform_options.json").unlink()
    assert load_model(tmp_path / "public")[1].scale_rule == "mirror"
    # a folder this project's trainer wrote before the rule was recorded: every preset floored then
    (tmp_path / "public/trainer_state").mkdir()
    assert load_model(tmp_path / "public")[1].scale_rule == "clamp"
    (tmp_path / "clamp/deform/iteration_3/deform_options.json").write_text("{not json")
    with pytest.raises(CheckpointError, match="deform_options.json: unreadable"):
        load_model(tmp_path / "clamp")
