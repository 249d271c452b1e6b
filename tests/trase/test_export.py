import numpy as np
import torch

from tests.trase.helpers import tiny_scene
from trase.export import export_clusters, export_ply
from trase.gaussians import GaussianModel


def test_ply_roundtrip_with_features_and_clusters(tmp_path):
    from plyfile import PlyData

    gm, _, ids, _ = tiny_scene(n_per=5)
    feats = np.random.default_rng(0).standard_normal((10, 6)).astype(np.float32)
    p = export_ply(gm, feats, tmp_path / "point_cloud.ply", labels=ids)
    back = GaussianModel.load_ply(p)
    np.testing.assert_array_equal(back.features.detach().numpy(), feats)
    np.testing.assert_array_equal(back.means.detach().numpy(), gm.means.detach().numpy())
    v = PlyData.read(str(p))["vertex"]
    assert "gaussian_feats_5" in v.data.dtype.names
    np.testing.assert_array_equal(np.asarray(v["cls"]), ids.astype(np.float32))


def test_clusters_files(tmp_path):
    paths = export_clusters(tmp_path, np.array([0, 2, 1]), torch.ones(3, 2))
    assert np.load(paths["clusters_npy"]).tolist() == [0, 2, 1]
    assert torch.load(paths["clusters_pt"], weights_only=False)["id"].tolist() == [0, 2, 1]
    assert np.load(paths["features_npy"]).shape == (3, 2)
