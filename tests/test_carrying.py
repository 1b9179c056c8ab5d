"""The fused CPU carry (`splatreel.carrying`, what float32 skinned models on the CPU use) against the torch
composition of `splatreel.skinned.carry` in float64: values and the gradients of the means, covariances and node
poses, for a subset of rows; and a skinned slice through it against the torch path."""

import torch

from splatreel import quaternion
from splatreel.carrying import fused_carry
from splatreel.skinned import SkinnedGaussians, carry, node_poses, skin_weights
from test_model import random_model


def inputs(n=300, m=24, seed=3):
    gen = torch.Generator().manual_seed(seed)
    means = torch.randn(n, 3, generator=gen, dtype=torch.float64)
    lower = torch.randn(n, 3, 3, generator=gen, dtype=torch.float64) * 0.1
    cov = lower @ lower.transpose(1, 2)
    canonical = torch.randn(m, 3, generator=gen, dtype=torch.float64)
    positions = canonical + 0.3 * torch.randn(m, 3, generator=gen, dtype=torch.float64)
    turns = quaternion.to_rotmat(quaternion.normalize(torch.randn(m, 4, generator=gen, dtype=torch.float64)))
    nodes, weights = skin_weights(means, canonical, 0.7)
    return means, cov, nodes, weights, canonical, positions, turns


def leaves(tensors, dtype):
    return [t.detach().to(dtype).requires_grad_(True) for t in tensors]


def test_fused_carry_matches_the_torch_composition_in_values_and_gradients():
    means, cov, nodes, weights, canonical, positions, turns = inputs()
    rows = torch.randperm(len(means), generator=torch.Generator().manual_seed(1))[:200]
    m32, c32, p32, r32 = leaves((means, cov[rows], positions, turns), torch.float32)
    m64, c64, p64, r64 = leaves((means, cov[rows], positions, turns), torch.float64)
    fused = fused_carry(m32, c32, rows, nodes[rows], weights[rows].float(), canonical.float(), p32, r32)
    reference = carry(m64[rows], c64, nodes[rows], weights[rows], canonical, p64, r64)
    for a, b in zip(fused, reference):
        assert a.dtype == torch.float32 and a.shape == b.shape
        assert torch.allclose(a.double(), b, rtol=1e-5, atol=1e-5)

    gen = torch.Generator().manual_seed(2)
    w_means, w_cov = torch.randn(200, 3, generator=gen), torch.randn(200, 3, 3, generator=gen)  # G not symmetric
    ((fused[0] * w_means).sum() + (fused[1] * w_cov).sum()).backward()
    ((reference[0] * w_means.double()).sum() + (reference[1] * w_cov.double()).sum()).backward()
    for a, b, name in ((m32, m64, "means"), (c32, c64, "cov"), (p32, p64, "positions"), (r32, r64, "turns")):
        assert float((a.grad.double() - b.grad).abs().max()) <= 1e-5 * float(b.grad.abs().max()), name
    unlisted = torch.ones(len(means), dtype=torch.bool)
    unlisted[rows] = False
    assert not m32.grad[unlisted].any()  # Gaussians not carried get no gradient


def test_fused_carry_without_covariances_moves_the_means_alike():
    means, _, nodes, weights, canonical, positions, turns = inputs(seed=4)
    rows = torch.arange(len(means))
    moved, cov = fused_carry(means.float(), None, rows, nodes, weights.float(), canonical.float(), positions.float(),
                             turns.float())
    assert cov is None
    assert torch.allclose(moved.double(), carry(means, None, nodes, weights, canonical, positions, turns)[0],
                          atol=1e-5)


def test_a_skinned_slice_on_the_cpu_equals_the_torch_path():
    native = random_model(150, "current", sh_degree=0, sh_degree_t=0, seed=7)
    gen = torch.Generator().manual_seed(8)
    canonical = torch.randn(12, 3, generator=gen)
    times = torch.tensor([0.0, 0.5, 1.0])
    positions = canonical + 0.2 * torch.randn(3, 12, 3, generator=gen)
    rotations = torch.randn(3, 12, 4, generator=gen)

    def skinned(dtype):
        g = native.to(dtype=dtype)
        return SkinnedGaussians(g, canonical.to(dtype), times.to(dtype), positions.to(dtype), rotations.to(dtype),
                                0.8)

    rows = torch.zeros(150, dtype=torch.bool)
    rows[::3] = True
    fast, slow = skinned(torch.float32).slice(0.3, rows=rows), skinned(torch.float64).slice(0.3, rows=rows)
    for name in ("means", "covariances"):
        assert torch.allclose(getattr(fast, name).double(), getattr(slow, name), rtol=1e-4, atol=1e-5), name
    # a central difference over a thousandth of the clip: float32 positions leave ~1e-4 of noise in it
    assert torch.allclose(fast.velocities.double(), slow.velocities, rtol=1e-3, atol=1e-3)
    p, r = node_poses(times, positions, rotations, 0.3)  # the poses the slice carried by
    assert torch.allclose(fast.means.double(), carry(native.means.double()[rows], None, *(x[rows] for x in skinned(
        torch.float64).skin), canonical.double(), p.double(), r.double())[0], atol=1e-5)
    # the centres (bounds, framing, mesh export) take the same kernel
    (means, visible), = skinned(torch.float32).centres([0.3])
    assert torch.allclose(means[rows].double(), slow.means, rtol=1e-4, atol=1e-5)
    assert torch.equal(visible[rows], slow.visible)
