"""The fused CPU projection (`splatreel.projecting`, what float32 renders on the CPU use) against the torch
composition `project_gaussians` + `conics_from_cov2d` in float64: values and gradients, clamped Jacobians included."""

import os
import sys

import torch

sys.path.insert(0, os.path.dirname(__file__))
from dense_rasterizer import camera, scene3d  # noqa: E402

from splatreel.constants import NEAR_PLANE  # noqa: E402
from splatreel.projecting import project_fused  # noqa: E402
from splatreel.rasterize import camera_depths, conics_from_cov2d, project_gaussians  # noqa: E402


def test_fused_projection_matches_the_torch_composition_in_values_and_gradients():
    cam = camera(48, 40)
    leaves = scene3d(300, 4)  # large, thin, off-screen and behind-the-camera Gaussians among them
    means64 = leaves["means"].clone().requires_grad_(True)
    cov64 = leaves["covariances"].clone().requires_grad_(True)
    means32 = leaves["means"].float().requires_grad_(True)
    cov32 = leaves["covariances"].float().requires_grad_(True)
    front = camera_depths(means64.detach(), cam) > NEAR_PLANE
    assert 0 < int(front.sum()) < 300
    rows = front.nonzero()[:, 0]
    lim = 1.3 * 0.5 * 48 / cam.fx
    p = means64.detach() @ torch.as_tensor(cam.w2c[:3, :3]).T + torch.as_tensor(cam.w2c[:3, 3])
    clamped = front & ((p[:, 0] / p[:, 2]).abs() > lim)
    assert int(clamped.sum()) >= 5  # the Jacobian clamp's branch is exercised

    reference = project_gaussians(means64[rows], cov64[rows], cam)
    ref_conics = conics_from_cov2d(reference.cov2d)
    means2d, depths, cov2d, conics = project_fused(means32, cov32, front, cam)
    assert torch.allclose(means2d[rows].double(), reference.means2d, rtol=1e-5, atol=1e-3)
    assert torch.allclose(depths[rows].double(), reference.depths, rtol=1e-5, atol=1e-5)
    assert torch.allclose(cov2d[rows].double(), reference.cov2d, rtol=1e-4, atol=1e-3)
    assert torch.allclose(conics[rows].double(), ref_conics, rtol=1e-3, atol=1e-4)
    assert not means2d[~front].any() and torch.equal(conics[~front], torch.tensor([1.0, 0.0, 1.0]).expand(
        int((~front).sum()), 3))

    gen = torch.Generator().manual_seed(8)
    w_uv, w_z, w_conic = torch.randn(300, 2, generator=gen), torch.randn(300, generator=gen), torch.randn(
        300, 3, generator=gen)
    ((reference.means2d * w_uv[rows].double()).sum() + (reference.depths * w_z[rows].double()).sum()
     + (ref_conics * w_conic[rows].double()).sum()).backward()
    ((means2d * w_uv).sum() + (depths * w_z * front).sum() + (conics * w_conic).sum()).backward()
    for mine, theirs in ((means32.grad, means64.grad), (cov32.grad, cov64.grad)):
        scale = theirs[rows].abs().amax(dim=tuple(range(1, theirs.dim())), keepdim=True) + 1e-6
        assert float(((mine[rows].double() - theirs[rows]).abs() / scale).max()) < 2e-3
    assert not cov32.grad[~front].any()
