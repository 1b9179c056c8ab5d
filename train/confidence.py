"""Efficient4D's inconsistency-aware confidence maps (Efficient4D eq. 11-16).

For frame k of one view's video, Î_1 = Interp(I_{k-1}, I_{k+1}) and Î_2 = Interp(I_{k-2}, I_{k+2}) are made by
optical-flow frame interpolation (OpenCV DIS flow, both directions, warped half-way and averaged), then::

    C_rgb  = 1 - mean_pairs |I_k - Î|        (eq. 16; per pixel, averaged over RGB)
    C_ssim = mean_pairs SSIM_map(I_k, Î)     (eq. 12, the same averaging)

clamped to [0, 1]. Frames at the ends of the video have confidence 1; the second and second-to-last frames use the
only pair they have. The loss multiplies its L1 term by C_rgb and its D-SSIM term by C_ssim per pixel.
"""

from __future__ import annotations

import numpy as np
import torch

from .losses import ssim_map


def _flow(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Dense optical flow ``[H, W, 2]`` from RGB uint8 image a to b (DIS, medium preset)."""
    import cv2

    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
    ga, gb = (cv2.cvtColor(x, cv2.COLOR_RGB2GRAY) for x in (a, b))
    return dis.calc(ga, gb, None)


def _warp(img: np.ndarray, flow: np.ndarray) -> np.ndarray:
    """Backward-warp: out(x) = img(x + flow(x)) (bilinear, border replicate)."""
    import cv2

    h, w = flow.shape[:2]
    gx, gy = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    return cv2.remap(img, gx + flow[..., 0], gy + flow[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def interpolate_midframe(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The frame half-way between RGB uint8 frames a and b, by optical flow: the middle pixel x is taken from
    a at x - F_ab(x)/2 and from b at x - F_ba(x)/2 (flow sampled at x, a first-order approximation), averaged."""
    f_ab, f_ba = _flow(a, b), _flow(b, a)
    wa = _warp(a.astype(np.float32), -0.5 * f_ab)
    wb = _warp(b.astype(np.float32), -0.5 * f_ba)
    return np.clip(0.5 * (wa + wb) + 0.5, 0, 255).astype(np.uint8)


def confidence_maps(frames: list[np.ndarray]) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Per-frame (C_rgb, C_ssim) maps ``[H, W]`` float32 in [0, 1] for one view's video of RGB uint8 frames
    (already composited on the training background)."""
    n = len(frames)
    ones = np.ones(frames[0].shape[:2], np.float32)
    c_rgb, c_ssim = [], []
    for k in range(n):
        pairs = [(k - d, k + d) for d in (1, 2) if k - d >= 0 and k + d < n]
        if k == 0 or k == n - 1 or not pairs:
            c_rgb.append(ones)
            c_ssim.append(ones)
            continue
        cur = torch.from_numpy(frames[k].astype(np.float32) / 255)
        er, es = [], []
        for i, j in pairs:
            est = torch.from_numpy(interpolate_midframe(frames[i], frames[j]).astype(np.float32) / 255)
            er.append((cur - est).abs().mean(-1))
            es.append(ssim_map(cur, est).mean(-1))
        c_rgb.append((1 - torch.stack(er).mean(0)).clamp(0, 1).numpy())
        c_ssim.append(torch.stack(es).mean(0).clamp(0, 1).numpy())
    return c_rgb, c_ssim
