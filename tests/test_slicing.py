"""The fused CPU slice (`splatreel.slicing`, what float32 models on the CPU use) against the torch composition of
`splatreel.covariance` in float64: values and the gradients of every parameter, for both rotation conventions."""

import pytest
import torch

from splatreel.model import Gaussians4D
from test_model import random_model

FIELDS = Gaussians4D.TENSORS


def leaf(model: Gaussians4D, dtype) -> Gaussians4D:
    return Gaussians4D(**{k: getattr(model, k).detach().to(dtype).requires_grad_(True) for k in FIELDS},
                       sh_degree=model.sh_degree, sh_degree_t=model.sh_degree_t, time_range=model.time_range,
                       rotation_convention=model.rotation_convention)


def weighted_sum(g, weights) -> torch.Tensor:
    """A loss that reaches every output of the slice with its own random weights."""
    parts = (g.means, g.covariances, g.velocities, g.opacities, g.sh)
    return sum((p * w.to(p.dtype)).sum() for p, w in zip(parts, weights))


@pytest.mark.parametrize("convention", ["current", "legacy"])
def test_fused_slice_matches_the_torch_composition_in_values_and_gradients(convention):
    base = random_model(400, convention, sh_degree=1, sh_degree_t=1, seed=5)
    rows = torch.randperm(400, generator=torch.Generator().manual_seed(1))[:250]
    t = 0.37
    fused, reference = leaf(base, torch.float32), leaf(base, torch.float64)
    g32 = fused.slice(t, rows=rows)  # float32 on the CPU: the numba kernel
    g64 = reference.select(rows)._slice_torch(t, None)  # the torch composition, float64
    for name in ("means", "covariances", "velocities", "opacities", "sh"):
        a, b = getattr(g32, name), getattr(g64, name)
        assert a.dtype == torch.float32 and a.shape == b.shape
        assert torch.allclose(a.double(), b, rtol=1e-4, atol=1e-5), name
    assert torch.equal(g32.visible, g64.visible)

    gen = torch.Generator().manual_seed(2)
    weights = [torch.randn(p.shape, generator=gen) for p in (g32.means, g32.covariances, g32.velocities,
                                                             g32.opacities, g32.sh)]
    weighted_sum(g32, weights).backward()
    weighted_sum(g64, weights).backward()
    unlisted = torch.ones(400, dtype=torch.bool)
    unlisted[rows] = False
    for name in FIELDS:
        a, b = getattr(fused, name).grad, getattr(reference, name).grad
        scale = b.abs().max()
        assert float((a.double() - b).abs().max()) <= 1e-4 * float(scale), name
        assert not a[unlisted].any(), f"{name}: Gaussians not sliced got gradients"


def test_fused_slice_of_every_gaussian_equals_slicing_a_selection():
    model = leaf(random_model(120, "current", sh_degree=0, sh_degree_t=0, seed=9), torch.float32)
    whole = model.slice(0.6)
    rows = torch.tensor([3, 50, 7, 119])
    part = model.slice(0.6, rows=rows)
    for name in ("means", "covariances", "opacities", "sh", "visible"):
        assert torch.equal(getattr(whole, name)[rows], getattr(part, name)), name
    mask = torch.zeros(120, dtype=torch.bool)
    mask[rows] = True
    assert torch.equal(model.slice(0.6, rows=mask).means, whole.means[mask])  # a mask, not indices 0 and 1
