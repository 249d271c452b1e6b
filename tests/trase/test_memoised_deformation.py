"""The memoised deformation (trase.memoised_deformation): one network pass per time, the same
bits as the plain call, and every call it cannot keep passed through."""

import torch

from trase.deformation import DeformMLP, deformed
from trase.gaussians import GaussianModel
from trase.memoised_deformation import MemoisedDeformation, memoised


class _Counted:
    """A deformation that counts its calls."""

    def __init__(self, inner):
        self.inner, self.calls, self.scale_rule = inner, 0, inner.scale_rule

    def __call__(self, xyz, t):
        self.calls += 1
        return self.inner(xyz, t)


def _model(n=50, seed=0):
    gen = torch.Generator().manual_seed(seed)
    return GaussianModel(torch.randn(n, 3, generator=gen), torch.zeros(n, 3), torch.tensor([[1.0, 0, 0, 0]] * n),
                         torch.zeros(n), torch.zeros(n, 1, 3))


def test_a_memoised_deformation_runs_the_network_once_per_time_and_returns_the_same_bits():
    torch.manual_seed(0)
    g, net = _model(), DeformMLP.preset("2x16", scale_rule="clamp")
    counted = _Counted(net)
    memo = MemoisedDeformation(counted, g.means)
    with torch.no_grad():
        first = deformed(g, memo, 0.3)
        again = deformed(g, memo, 0.3)
        other = deformed(g, memo, 0.7)
        plain = deformed(g, net, 0.3)
    assert counted.calls == 2 and (memo.hits, memo.misses) == (1, 2)
    for a, b, c in zip(first, again, plain):
        assert torch.equal(a, b) and torch.equal(a, c)
    assert not torch.equal(first[0], other[0])
    assert memo.scale_rule == "clamp"
    assert MemoisedDeformation(net, g.means).config() == net.config()  # the wrapped one's attributes
    assert memoised(None, g.means) is None and isinstance(memoised(net, g.means), MemoisedDeformation)


def test_a_memoised_deformation_passes_through_what_it_cannot_keep():
    torch.manual_seed(0)
    g, counted = _model(), _Counted(DeformMLP.preset("2x16"))
    memo = MemoisedDeformation(counted, g.means)
    with torch.no_grad():
        memo(g.means[:10], 0.3)  # a subset of the rows
        memo(g.means.detach(), 0.3)
        memo(g.means.detach(), 0.3)  # kept: the same storage
    out = memo(g.means, 0.3)  # with autograd: training is never served from the memo
    assert out[0].requires_grad
    with torch.no_grad():
        memo(g.means, torch.tensor(0.3))  # a tensor of times
        g.means.add_(1.0)  # the model moved: its old offsets are not served
        moved = memo(g.means, 0.3)
    assert counted.calls == 5 and memo.hits == 1
    assert torch.equal(moved[0], counted.inner(g.means, 0.3)[0])


def test_a_full_memo_computes_further_times_without_keeping_them():
    g, counted = _model(), _Counted(DeformMLP.preset("2x16"))
    per_time = sum(-(-50 * k * 4 // 64) * 64 for k in (3, 4, 3))  # bytes of one time's offsets, each aligned
    memo = MemoisedDeformation(counted, g.means, max_bytes=2 * per_time)
    with torch.no_grad():
        for _ in range(2):
            for t in (0.1, 0.2, 0.3):
                memo(g.means, t)
    assert (memo.misses, memo.hits, counted.calls) == (4, 2, 4)  # 0.1 and 0.2 kept, 0.3 computed twice
    assert memo.allocated == 2 * per_time
