"""Render a model at a dataset's views and score it (PSNR, SSIM; LPIPS when its weights are available)."""

from __future__ import annotations

import time

import numpy as np
import torch

from splatreel.datasets import DatasetImage
from splatreel.model import Model
from splatreel.rasterize import rasterize

from .losses import psnr, ssim

LPIPS_NOTE = ("LPIPS not computed: it needs pretrained network weights, which splatreel does not download and "
              "which are not available locally")


def view_target(view: DatasetImage, background, device="cpu") -> tuple[torch.Tensor, torch.Tensor | None]:
    """(RGB ``[H,W,3]`` composited on `background`, alpha ``[H,W]`` or None) as float32 tensors in [0, 1]."""
    return target_from_bytes(*view_bytes(view, device), background)


def view_bytes(view: DatasetImage, device="cpu") -> tuple[torch.Tensor, torch.Tensor | None]:
    """(RGB ``[H,W,3]``, alpha ``[H,W]`` or None) of the view as uint8 tensors on `device` (a quarter of the floats'
    memory: what a trainer keeps on a GPU)."""
    alpha = None if view.alpha is None else torch.from_numpy(view.alpha).to(device)
    return torch.from_numpy(view.image).to(device), alpha


def target_from_bytes(image: torch.Tensor, alpha: torch.Tensor | None, background
                      ) -> tuple[torch.Tensor, torch.Tensor | None]:
    """`view_target` of `view_bytes`, on their device."""
    rgb = image.to(torch.float32) / 255.0
    if alpha is None:
        return rgb, None
    a = alpha.to(torch.float32) / 255.0
    bg = torch.as_tensor(background, dtype=torch.float32, device=image.device)
    return rgb * a[..., None] + bg * (1 - a[..., None]), a


def target_bytes(view: DatasetImage, background) -> np.ndarray:
    """``[H, W, 3]`` uint8: `view_target`'s RGB rounded back to bytes (what OpenCV's flow and the confidence maps
    read)."""
    return (view_target(view, background)[0].numpy() * 255 + 0.5).astype(np.uint8)


def render_view(model: Model, view: DatasetImage, background, device="cpu", far_clip: float | None = None
                ) -> torch.Tensor:
    """``[H, W, 3]`` image of `model` at the view's camera and time, cut at the capture's `far_clip` (camera depth;
    None: none)."""
    with torch.no_grad():
        return rasterize(model.slice(view.time), view.camera, background, far_plane=far_clip).rgb


def evaluate(model: Model, views: list[DatasetImage], background, device="cpu", progress: bool = False,
             far_clip: float | None = None) -> dict:
    """Per-view and mean PSNR / SSIM of `model` rendered at `views` (top-level keys `psnr`, `ssim`, `lpips`,
    `per_view`, `seconds`, `far_clip`), cut at the capture's `far_clip` when it has one (`splatreel.train.far_clip`)."""
    from tqdm import tqdm

    start = time.perf_counter()
    per_view = []
    for v in tqdm(views, desc="eval", unit="view", disable=not progress, leave=False):
        target, _ = view_target(v, background, device)
        img = render_view(model, v, background, device, far_clip).clamp(0, 1)
        per_view.append({"name": v.name, "view": v.view_id, "frame": v.frame_id, "time": v.time,
                         "psnr": psnr(img, target), "ssim": float(ssim(img, target))})
    return {
        "psnr": float(np.mean([p["psnr"] for p in per_view])) if per_view else None,
        "ssim": float(np.mean([p["ssim"] for p in per_view])) if per_view else None,
        "lpips": None, "lpips_note": LPIPS_NOTE, "num_views": len(per_view), "per_view": per_view,
        "far_clip": far_clip,
        "seconds": time.perf_counter() - start,
    }


def _same_camera(test: DatasetImage, train: list[DatasetImage]) -> list[DatasetImage]:
    """The training views of the camera nearest to `test`'s (equal poses when the test camera is a training one;
    else the nearest centre, ties broken by viewing direction)."""
    def distance(v: DatasetImage) -> float:
        return float(np.linalg.norm(v.camera.position - test.camera.position)
                     + 0.1 * np.linalg.norm(v.camera.forward - test.camera.forward))

    best = min(distance(v) for v in train)
    return [v for v in train if distance(v) <= best + 1e-6]


def baselines(views: list[DatasetImage], train: list[DatasetImage], background) -> dict:
    """PSNR of two trivial predictors of each view in `views`, from the training views of the same (or nearest)
    camera: its training image nearest in time (`nearest_image`), and its per-pixel median image
    (`median_image`). A trained model has to beat both by a wide margin to have learnt anything."""
    scores: dict[str, list[float]] = {"nearest_image": [], "median_image": []}
    medians: dict[int, torch.Tensor] = {}
    for v in views:
        target, _ = view_target(v, background)
        same = _same_camera(v, train)
        if {u.size for u in same} != {v.size}:
            continue
        near = min(same, key=lambda u: abs(u.time - v.time))
        scores["nearest_image"].append(psnr(view_target(near, background)[0], target))
        key = id(same[0])
        if key not in medians:
            medians[key] = torch.stack([view_target(u, background)[0] for u in same]).median(0).values
        scores["median_image"].append(psnr(medians[key], target))
    return {k: float(np.mean(x)) if x else None for k, x in scores.items()}
