"""Image losses and metrics: L1, SSIM (separable Gaussian window), PSNR, confidence-weighted variants.

SSIM uses the reference constants (11x11 Gaussian window, sigma 1.5, C1 = 0.01^2, C2 = 0.03^2, data range 1) as
the official 4DGS and Efficient4D code, but filters with two 1-D passes (rows then columns): the same result as
the 2-D window at ~1/5 of the cost, which matters on a CPU where SSIM costs as much as the rasterizer.
Images are ``[..., H, W, C]`` float tensors in [0, 1] (channels last, like the rasterizer's output).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

SSIM_WINDOW = 11
SSIM_SIGMA = 1.5
SSIM_C1 = 0.01 ** 2
SSIM_C2 = 0.03 ** 2
#: How far from the pixels where two images differ their SSIM map can differ from 1: a pixel's window (radius 5)
#: reaches pixels whose own windows reach 5 further.
SSIM_REACH = 2 * (SSIM_WINDOW // 2)


def gaussian_kernel_1d(size: int = SSIM_WINDOW, sigma: float = SSIM_SIGMA, dtype=torch.float32) -> Tensor:
    x = torch.arange(size, dtype=torch.float64) - (size - 1) / 2
    g = torch.exp(-x * x / (2 * sigma * sigma))
    return (g / g.sum()).to(dtype)


def _to_nchw(img: Tensor) -> Tensor:
    """``[..., H, W, C]`` -> ``[B, C, H, W]``."""
    h, w, c = img.shape[-3:]
    return img.reshape(-1, h, w, c).permute(0, 3, 1, 2)


def _blur(x: Tensor, kernel: Tensor) -> Tensor:
    """Separable Gaussian filter with zero padding ("same" size, as the reference conv2d with padding=5)."""
    c = x.shape[1]
    k = kernel.to(x)
    pad = k.numel() // 2
    x = F.conv2d(x, k.view(1, 1, 1, -1).expand(c, 1, 1, -1), padding=(0, pad), groups=c)
    return F.conv2d(x, k.view(1, 1, -1, 1).expand(c, 1, -1, 1), padding=(pad, 0), groups=c)


def ssim_map(a: Tensor, b: Tensor) -> Tensor:
    """Per-pixel SSIM ``[..., H, W, C]`` of two images ``[..., H, W, C]``."""
    x, y = _to_nchw(a), _to_nchw(b)
    k = gaussian_kernel_1d(dtype=x.dtype)
    # one conv call for all five moments
    stats = _blur(torch.cat([x, y, x * x, y * y, x * y], 1), k)
    mx, my, sxx, syy, sxy = stats.chunk(5, 1)
    mx2, my2, mxy = mx * mx, my * my, mx * my
    num = (2 * mxy + SSIM_C1) * (2 * (sxy - mxy) + SSIM_C2)
    den = (mx2 + my2 + SSIM_C1) * ((sxx - mx2) + (syy - my2) + SSIM_C2)
    out = (num / den).permute(0, 2, 3, 1)
    return out.reshape(a.shape)


def ssim(a: Tensor, b: Tensor) -> Tensor:
    """Mean SSIM (scalar)."""
    return ssim_map(a, b).mean()


def l1(a: Tensor, b: Tensor, weight: Tensor | None = None) -> Tensor:
    """Mean absolute error, optionally weighted per pixel by ``weight`` ``[..., H, W]`` or ``[..., H, W, C]``."""
    d = (a - b).abs()
    if weight is None:
        return d.mean()
    if weight.dim() == d.dim() - 1:
        weight = weight[..., None]
    return (d * weight).mean()


def dssim(a: Tensor, b: Tensor, weight: Tensor | None = None) -> Tensor:
    """1 - SSIM, optionally weighted per pixel (Efficient4D's confidence-weighted SSIM term)."""
    m = 1.0 - ssim_map(a, b)
    if weight is None:
        return m.mean()
    if weight.dim() == m.dim() - 1:
        weight = weight[..., None]
    return (m * weight).mean()


def mse(a: Tensor, b: Tensor) -> Tensor:
    """Mean squared error (a detached scalar tensor) of `a` clamped to [0, 1] against `b`: what `psnr` scores."""
    return ((a.detach().clamp(0, 1) - b.detach()) ** 2).mean()


def psnr_of_mse(err: Tensor) -> Tensor:
    """PSNR in dB of mean squared errors (images in [0, 1]), elementwise; inf where the error is 0."""
    return -10.0 * torch.log10(err)


def psnr(a: Tensor, b: Tensor) -> float:
    """PSNR in dB over all pixels and channels (images in [0, 1])."""
    return float(psnr_of_mse(mse(a, b).double()))


def loss_window(rendered: Tensor, target: Tensor) -> tuple[slice, slice]:
    """Rows and columns of the box, grown by `SSIM_REACH` and clipped to the image, outside which both ``[H, W]``
    alphas are zero (the whole image when both are; any box would do then).

    Where a render and its target both show nothing but the background, the L1 and D-SSIM terms are zero with zero
    gradient, and the SSIM windows of the box's pixels see the same pixels in the box as in the whole image (or the
    same zero padding): each term summed over the box equals the whole image's sum (`image_loss`).
    """
    covered = (rendered > 0) | (target > 0)
    h, w = covered.shape
    rows = torch.nonzero(covered.any(1)).flatten()
    if rows.numel() == 0:
        return slice(0, h), slice(0, w)
    cols = torch.nonzero(covered.any(0)).flatten()
    r0, r1, c0, c1 = int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1
    return (slice(max(r0 - SSIM_REACH, 0), min(r1 + SSIM_REACH, h)),
            slice(max(c0 - SSIM_REACH, 0), min(c1 + SSIM_REACH, w)))


def image_loss(rgb: Tensor, alpha: Tensor, target: Tensor, mask: Tensor | None, l1_weight: float,
               dssim_weight: float, mask_weight: float,
               pixel_weights: tuple[Tensor | None, Tensor | None, Tensor | None] = (None, None, None)) -> Tensor:
    """The training loss of one render: ``l1_weight L1(rgb) + dssim_weight D-SSIM(rgb) + mask_weight L1(alpha)``,
    each a mean over the image's pixels, optionally weighted per pixel (`pixel_weights`: ``[H, W]`` maps for the
    three terms, e.g. confidence maps). The alpha term needs a `mask` (the target's alpha).

    With a `mask`, on the CPU, the terms are computed over `loss_window` only, the box where the render or the target
    is not the background, and scaled by its share of the image: the same loss and gradients as over the whole
    image, at a fraction of the cost when the subject covers a fraction of the frame (an object on a transparent
    background). Not on a GPU: there the whole image costs little, and a box of a new size each image makes cuDNN
    choose its convolution algorithms again for every render (about 11 ms of host time per SSIM backward on an
    H100, against microseconds for the convolution itself).
    """
    if mask is None:
        return l1_weight * l1(rgb, target, pixel_weights[0]) + dssim_weight * dssim(rgb, target, pixel_weights[1])
    height, width = mask.shape
    whole = (slice(0, height), slice(0, width))
    rows, cols = loss_window(alpha.detach(), mask) if mask.device.type == "cpu" else whole
    share = (rows.stop - rows.start) * (cols.stop - cols.start) / (height * width)
    w_rgb, w_ssim, w_alpha = (None if w is None else w[rows, cols] for w in pixel_weights)
    rgb, target = rgb[rows, cols], target[rows, cols]
    loss = l1_weight * l1(rgb, target, w_rgb) + dssim_weight * dssim(rgb, target, w_ssim)
    if mask_weight:
        loss = loss + mask_weight * l1(alpha[rows, cols], mask[rows, cols], w_alpha)
    return share * loss


def smoothness_loss(velocities: torch.Tensor, nbr: torch.Tensor, nbr_dist: torch.Tensor) -> torch.Tensor:
    """Temporal smoothness for native 4D Gaussians: each Gaussian moves linearly, so the acceleration of the
    surface comes from neighbouring Gaussians moving differently; penalise ||v_i - v_j|| over the k nearest
    neighbours with weights exp(-100 d) (the official lambda_rigid form, standing in for 4DGen's acceleration
    penalty)."""
    w = torch.exp(-100.0 * nbr_dist)
    diff = torch.linalg.vector_norm(velocities[:, None, :] - velocities[nbr], dim=-1)
    return (w * diff).sum(-1).mean() / nbr.shape[1]


def scale_ratio_loss(log_scales: torch.Tensor, max_ratio: float) -> torch.Tensor:
    """PhysGaussian's anisotropy penalty (nerfstudio splatfacto `use_scale_regularization`):
    mean(max(s_max / s_min, r) - r) over the spatial scales, so no Gaussian grows into a needle or a sheet thinner
    than 1 / r of its width unless the images pay for it."""
    ratio = torch.exp(log_scales.max(-1).values - log_scales.min(-1).values)
    return (ratio.clamp_min(max_ratio) - max_ratio).mean()
