"""Smoke, bad-input, degenerate-input and gradcheck tests run for every baseline objective."""

from __future__ import annotations

import pytest
import torch
from baseline_helpers import NAMES, make_sample, random_case

from baselines.cgc import cgc_labels
from trase.objectives import Objective, ObjectiveInputError, get_objective, pair_stats


@pytest.mark.parametrize("name", NAMES)
def test_registered_by_name(name):
    obj = get_objective(name)
    assert isinstance(obj, Objective) and obj.name == name


@pytest.mark.parametrize("name", NAMES)
def test_smoke_loss_and_gradient(name):
    f, s = random_case(0, n=12, m=4, d=6)
    f.requires_grad_(True)
    loss, stats = get_objective(name)(f, s)
    assert loss.ndim == 0 and torch.isfinite(loss)
    assert all(isinstance(v, (int, float)) for v in stats.values())
    loss.backward()
    assert torch.isfinite(f.grad).all() and f.grad.abs().sum() > 0


@pytest.mark.parametrize("name", NAMES)
def test_wrong_feature_count_is_a_clear_error(name):
    _, s = random_case(1)
    with pytest.raises(ObjectiveInputError, match=r"features must be \[Np=8, D\]"):
        get_objective(name)(torch.zeros(5, 4, dtype=torch.float64), s)


@pytest.mark.parametrize("name", NAMES)
def test_integer_features_are_a_clear_error(name):
    _, s = random_case(1)
    with pytest.raises(ObjectiveInputError, match="floating point"):
        get_objective(name)(torch.zeros(8, 4, dtype=torch.long), s)


def _degenerate_cases():
    n = 6
    yield (
        "zero features",
        torch.zeros(n, 4),
        make_sample([[1, 0], [1, 0], [0, 1], [0, 1], [1, 1], [0, 0]]),
    )
    yield "one mask", torch.randn(n, 4), make_sample([[1]] * n)
    yield "no masks", torch.randn(n, 4), make_sample(torch.zeros(n, 0))
    yield "no pixel in a mask", torch.randn(n, 4), make_sample([[0, 0]] * n)
    yield "single pixel", torch.randn(1, 4), make_sample([[1, 1]])
    yield "no pixels", torch.randn(0, 4), make_sample(torch.zeros(0, 2))
    yield (
        "empty silhouette",
        torch.randn(n, 4),
        make_sample([[1, 0]] * 3 + [[0, 1]] * 3, alpha=[0.0] * n),
    )
    yield "identical features", torch.ones(n, 4), make_sample([[1, 0]] * 3 + [[0, 1]] * 3)


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("case", list(_degenerate_cases()), ids=lambda c: c[0])
def test_degenerate_input_is_finite(name, case):
    _, f, s = case
    f = f.to(torch.float64).requires_grad_(True)
    loss, stats = get_objective(name)(f, s)
    assert torch.isfinite(loss), stats
    loss.backward()
    assert f.grad is not None and torch.isfinite(f.grad).all()


def _margins_ok(name, f, s) -> bool:
    """Gradcheck needs every discrete choice (selection thresholds, relu kink, CGC's clipped
    detached temperature, OpenGaussian's ranks) to be locally constant."""
    ps = pair_stats(f, s)
    off = ~torch.eye(ps.CF.shape[0], dtype=torch.bool)
    cf = ps.CF[off]
    if name in ("trase-hard", "trase-all"):
        return bool(
            ((cf - 0.75).abs() > 1e-3).all()
            and ((cf - 0.5).abs() > 1e-3).all()
            and (cf.abs() > 1e-3).all()
        )
    if name == "cgc":
        labels = cgc_labels(s.membership, s.mask_area)
        fn = torch.nn.functional.normalize(f, dim=1)
        for lab in labels.unique():
            if lab < 0:
                continue
            x = fn[labels == lab]
            n = x.shape[0]
            phi = 10 * (x - x.mean(0)).norm(dim=1).sum() / (n * torch.log(torch.tensor(n + 100.0)))
            if 0.099 < phi < 1.01:
                return False
        return True
    return True


@pytest.mark.parametrize("name", NAMES)
def test_gradcheck(name):
    obj = get_objective(name)
    for seed in range(50):
        f, s = random_case(seed, n=7, m=3, d=3)
        if _margins_ok(name, f, s):
            break
    else:
        pytest.fail("no random case with safe margins")
    f.requires_grad_(True)
    assert torch.autograd.gradcheck(lambda x: obj(x, s)[0], (f,), eps=1e-6, atol=1e-6)
