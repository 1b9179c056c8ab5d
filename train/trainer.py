"""The training loop: fit a `Gaussians4D` to a `Dataset` with one of the recipes of `config`.

`Trainer` is the stateful edge (parameters, Adam, random generator, densification statistics); everything it calls
is a pure function elsewhere in this package. A run writes ``OUT`` (a splat4d checkpoint) and, beside it,
``OUT.state.pt`` (optimizer moments, random state, iteration) so that ``resume`` continues bit for bit.
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from splat4d.cameras import DatasetView
from splat4d.checkpoint import load_checkpoint, save_checkpoint
from splat4d.errors import CheckpointError, OutputExistsError, Splat4DError
from splat4d.fileio import atomic_path
from splat4d.model import Gaussians4D

from . import strategy
from .alpha_conflicts import AlphaConflicts, find_alpha_conflicts
from .config import TrainConfig
from .confidence import confidence_maps
from .data import Dataset, View, downscale_view, relative_name
from .evaluate import evaluate, view_target
from .initialize import (carved_init, default_init_radius, knn, initial_parameters, look_at_centre, mesh_points,
                         random_ball)
from .losses import dssim, l1, psnr
from .rasterize import rasterize

PARAM_NAMES = Gaussians4D.TENSORS


def state_path(out: Path) -> Path:
    """Where the resumable training state of checkpoint `out` lives."""
    return out.with_suffix(".state.pt")


def pick_device(name: str) -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise Splat4DError("--device cuda requested but no CUDA device is available")
    return torch.device(name)


def mean_lr(step: int, cfg: TrainConfig, extent: float) -> float:
    """Exponential decay from lr_means to lr_means_final over the run (official `get_expon_lr_func`)."""
    u = min(max(step / max(cfg.iters, 1), 0.0), 1.0)
    lr0, lr1 = cfg.lr_means * extent, cfg.lr_means_final * extent
    return math.exp((1 - u) * math.log(lr0) + u * math.log(lr1))


def active_sh(step: int, cfg: TrainConfig) -> tuple[int, int]:
    """(spatial, time) SH degree in use at `step`: spatial first, then time, one more every sh_increase_every."""
    if not cfg.sh_increase_every:
        return cfg.sh_degree, cfg.sh_degree_t
    k = step // cfg.sh_increase_every
    return min(k, cfg.sh_degree), min(max(0, k - cfg.sh_degree), cfg.sh_degree_t)


def smoothness_loss(velocities: torch.Tensor, nbr: torch.Tensor, nbr_dist: torch.Tensor) -> torch.Tensor:
    """Temporal smoothness for native 4D Gaussians: each Gaussian moves linearly, so the acceleration of the
    surface comes from neighbouring Gaussians moving differently; penalise ||v_i - v_j|| over the k nearest
    neighbours with weights exp(-100 d) (the official lambda_rigid form, standing in for 4DGen's acceleration
    penalty)."""
    w = torch.exp(-100.0 * nbr_dist)
    diff = torch.linalg.vector_norm(velocities[:, None, :] - velocities[nbr], dim=-1)
    return (w * diff).sum(-1).mean() / nbr.shape[1]


@dataclass
class TrainResult:
    out: Path
    iterations: int
    seconds: float
    n_gaussians: int
    train_psnr: float
    losses: list[float] = field(default_factory=list)
    test: dict | None = None


class Trainer:
    """Holds a run's state; `run` trains to `config.iters` (or `stop_at`), writing checkpoints."""

    def __init__(self, dataset: Dataset, config: TrainConfig, out: str | os.PathLike, resume: bool = False,
                 force: bool = False, progress: bool = True):
        self.ds, self.cfg, self.out, self.progress = dataset, config, Path(out), progress
        self.device = pick_device(config.device)
        self.bg = torch.tensor(dataset.background, dtype=torch.float32, device=self.device)
        _, cam_radius = dataset.camera_centre_and_radius()
        self.extent = 1.1 * max(cam_radius, 1e-3)  # official cameras_extent
        self.time_range = dataset.time_range
        self.generator = torch.Generator().manual_seed(config.seed)
        self.step = 0
        self.losses: list[float] = []
        self._views_at: dict[int, list[View]] = {1: dataset.train}
        self._conf = self._confidence() if config.confidence else {}
        self.alpha_conflicts: AlphaConflicts = find_alpha_conflicts(dataset)
        self._alpha_weight: dict[tuple[int, int], torch.Tensor | None] = {}
        if resume:
            self._resume()
        else:
            if self.out.exists() and not force:
                raise OutputExistsError(f"{self.out} already exists (use --force to overwrite, or --resume)")
            self._init_params()
        self.strategy_state = strategy.initialize_state(len(self.params["means"]), self.device)
        if resume and "strategy" in self._loaded_state:
            self.strategy_state = {k: v.to(self.device) for k, v in self._loaded_state["strategy"].items()}
        self._nbr = None

    # --- set-up ---------------------------------------------------------------------------------------------
    def _init_params(self) -> None:
        cfg = self.cfg
        t_means = None
        if cfg.init_mesh:
            points, rgb = mesh_points(cfg.init_mesh, cfg.num_gaussians, cfg.seed)
        else:
            centre = look_at_centre(self.ds)
            radius = cfg.init_radius or default_init_radius(self.ds, centre)
            hull = carved_init(cfg.num_gaussians, radius, centre, self.ds, self.generator) if cfg.init_carve else None
            if hull is not None:
                points, t_means = hull
            else:
                points = random_ball(cfg.num_gaussians, radius, centre, self.generator)
            rgb = 0.5 + 0.05 * torch.randn(points.shape, generator=self.generator)
        t_scale = None
        if cfg.t_scale_init_frames:
            times = self.ds.frame_times
            step = (times[-1] - times[0]) / max(len(times) - 1, 1)
            t_scale = cfg.t_scale_init_frames * step
        raw = initial_parameters(points, rgb, self.time_range, cfg.sh_degree, cfg.sh_degree_t, self.generator,
                                 t_scale, t_means)
        self._make_optimizer(raw)
        self._loaded_state = {}

    def _make_optimizer(self, raw: dict[str, torch.Tensor]) -> None:
        cfg = self.cfg
        self.params = {k: torch.nn.Parameter(raw[k].to(self.device, torch.float32).contiguous())
                       for k in PARAM_NAMES}
        lrs = {"means": mean_lr(0, cfg, self.extent), "t_means": cfg.lr_t_means * self.extent,
               "log_scales": cfg.lr_scales, "log_t_scales": cfg.lr_scales, "quats_l": cfg.lr_quats,
               "quats_r": cfg.lr_quats, "opacity_logits": cfg.lr_opacity, "sh_dc": cfg.lr_sh_dc,
               "sh_rest": cfg.lr_sh_rest}
        self.optimizer = torch.optim.Adam([{"params": [self.params[k]], "lr": lrs[k], "name": k}
                                           for k in PARAM_NAMES], lr=0.0, eps=1e-15)

    def _resume(self) -> None:
        sp = state_path(self.out)
        if not self.out.exists() or not sp.exists():
            raise CheckpointError(f"cannot resume: {self.out if not self.out.exists() else sp} not found")
        ck = load_checkpoint(self.out)
        if ck.model.kind != "gaussians4d":
            raise CheckpointError(f"{self.out}: cannot resume training of a {ck.model.kind} model")
        try:
            st = torch.load(sp, map_location="cpu", weights_only=True)
        except Exception as exc:
            raise CheckpointError(f"{sp}: unreadable training state ({str(exc).strip().splitlines()[0]})") from None
        self._make_optimizer(ck.model.tensors())
        self.optimizer.load_state_dict(st["optimizer"])
        self.generator.set_state(st["generator"])
        self.step = int(st["step"])
        self.losses = list(st.get("losses", []))
        self._loaded_state = st

    def _confidence(self) -> dict[int, tuple[torch.Tensor, torch.Tensor]]:
        """Confidence maps for every training image whose view has a video of >= 3 frames at consecutive dataset
        times. A camera that sees only every k-th time (one camera per time, cameras taking turns) has no video:
        interpolating its frames k steps apart fails on everything that moves, and would down-weight exactly the
        moving objects."""
        by_view: dict[int, list[int]] = {}
        for i, v in enumerate(self.ds.train):
            by_view.setdefault(v.view_id, []).append(i)
        rank = {t: k for k, t in enumerate(self.ds.frame_times)}
        out = {}
        for idx in by_view.values():
            idx = sorted(idx, key=lambda i: self.ds.train[i].time)
            ranks = [rank[self.ds.train[i].time] for i in idx]
            if len(idx) < 3 or ranks != list(range(ranks[0], ranks[0] + len(ranks))):
                continue
            frames = [(view_target(self.ds.train[i], self.ds.background)[0].numpy() * 255 + 0.5).astype(np.uint8)
                      for i in idx]
            c_rgb, c_ssim = confidence_maps(frames)
            for i, a, b in zip(idx, c_rgb, c_ssim):
                out[i] = (torch.from_numpy(a).to(self.device), torch.from_numpy(b).to(self.device))
        return out

    # --- one step -------------------------------------------------------------------------------------------
    def model(self) -> Gaussians4D:
        cfg = self.cfg
        return Gaussians4D(**self.params, sh_degree=cfg.sh_degree, sh_degree_t=cfg.sh_degree_t,
                           time_range=self.time_range, rotation_convention=cfg.rotation_convention)

    def _views(self, factor: int) -> list[View]:
        if factor not in self._views_at:
            self._views_at[factor] = [downscale_view(v, factor) for v in self.ds.train]
        return self._views_at[factor]

    def _resolution_factor(self) -> int:
        for frac, k in self.cfg.resolution_ramp:
            if self.step < frac * self.cfg.iters:
                return int(k)
        return 1

    def _pick(self) -> int:
        """Index of the next training image (uniform, from the run's own generator)."""
        static = self.step < self.cfg.static_iters
        if static:
            first = min(v.frame_id for v in self.ds.train)
            pool = [i for i, v in enumerate(self.ds.train) if v.frame_id == first]
            return pool[int(torch.randint(len(pool), (1,), generator=self.generator))]
        return int(torch.randint(len(self.ds.train), (1,), generator=self.generator))

    def _loss_weights(self, i: int, factor: int) -> tuple[torch.Tensor | None, ...]:
        """Per-pixel weights of training image `i` at 1/`factor` resolution for the L1, D-SSIM and alpha terms:
        the confidence maps (full resolution only) times the alpha-conflict weight (0 where the image's
        transparency contradicts the other views, unless `strict_alpha`)."""
        key = (i, factor)
        if key not in self._alpha_weight:
            w = None if self.cfg.strict_alpha or not self.alpha_conflicts.detected else \
                self.alpha_conflicts.weight(self.ds.train[i])
            if w is not None and factor > 1:
                import cv2

                size = self._views(factor)[i].size
                w = cv2.resize(w, size, interpolation=cv2.INTER_AREA)
            self._alpha_weight[key] = None if w is None else torch.from_numpy(w).to(self.device)
        w_alpha = self._alpha_weight[key]
        conf = self._conf.get(i) if factor == 1 else None
        if conf is None:
            return w_alpha, w_alpha, w_alpha
        if w_alpha is None:
            return conf[0], conf[1], None
        return conf[0] * w_alpha, conf[1] * w_alpha, w_alpha

    def train_step(self) -> tuple[float, float]:
        cfg = self.cfg
        for g in self.optimizer.param_groups:
            if g["name"] == "means":
                g["lr"] = mean_lr(self.step, cfg, self.extent)
        deg, deg_t = active_sh(self.step, cfg)
        factor = self._resolution_factor()
        static = self.step < cfg.static_iters
        loss_sum, psnr_sum = 0.0, 0.0
        model = self.model()  # the parameters only change at the optimizer step, after the batch
        for _ in range(cfg.batch_size):
            i = self._pick()
            view = self._views(factor)[i]
            target, mask = view_target(view, self.ds.background, self.device)
            g = model.slice(view.time, sh_degree_t=deg_t)
            out = rasterize(g, view.camera, self.bg, sh_degree=deg)
            if cfg.densify.enabled:
                out.means2d.retain_grad()
            w_rgb, w_ssim, w_alpha = self._loss_weights(i, factor)
            loss = cfg.lambda_l1 * l1(out.rgb, target, w_rgb) + cfg.lambda_dssim * dssim(out.rgb, target, w_ssim)
            if mask is not None and cfg.lambda_mask:
                loss = loss + cfg.lambda_mask * l1(out.alpha, mask, w_alpha)
            if cfg.smooth_weight and not static:
                if self._nbr is None or self.step % 100 == 0:
                    self._nbr = knn(self.params["means"].detach(), k=8)
                loss = loss + cfg.smooth_weight * smoothness_loss(g.velocities, *self._nbr)
            (loss / cfg.batch_size).backward()
            if cfg.densify.enabled and out.means2d.grad is not None:
                strategy.accumulate(self.strategy_state, out.means2d.grad, out.radii, view.camera.width,
                                    view.camera.height)
            loss_sum += float(loss.detach())
            psnr_sum += psnr(out.rgb, target)
        if static:  # static-to-dynamic: time frozen, q_r tied to q_l (static under the 'current' convention)
            for k in ("t_means", "log_t_scales", "quats_r"):
                self.params[k].grad = None
        self._maybe_densify()
        self.optimizer.step()
        self.optimizer.zero_grad(set_to_none=True)
        if static:
            with torch.no_grad():
                self.params["quats_r"].copy_(self.params["quats_l"])
        self.step += 1
        return loss_sum / cfg.batch_size, psnr_sum / cfg.batch_size

    def _maybe_densify(self) -> None:
        d = self.cfg.densify
        if not d.enabled:
            return
        s = self.step + 1
        if d.start < s < d.stop and s % d.every == 0:
            strategy.densify_and_prune(self.params, self.optimizer, self.strategy_state, d, self.extent, s,
                                       self.cfg.rotation_convention, self.generator)
            self._nbr = None
        if d.opacity_reset_every and s % d.opacity_reset_every == 0 and s < d.stop:
            strategy.reset_opacity(self.params, self.optimizer)

    # --- output ---------------------------------------------------------------------------------------------
    def save(self) -> None:
        """Write the checkpoint and the resumable state beside it (both atomically)."""
        model = Gaussians4D(**{k: v.detach().cpu() for k, v in self.params.items()},
                            sh_degree=self.cfg.sh_degree, sh_degree_t=self.cfg.sh_degree_t,
                            time_range=self.time_range, rotation_convention=self.cfg.rotation_convention)
        found = self.alpha_conflicts
        training = {**self.cfg.to_dict(), "iteration": self.step, "dataset": str(self.ds.root),
                    "layout": self.ds.layout, "background_reason": self.ds.background_reason,
                    "alpha_disagreement": round(found.worst_share, 4) if found.checked else None,
                    "alpha_ignored": bool(found.detected and not self.cfg.strict_alpha)}
        save_checkpoint(self.out, model, background=self.ds.background, force=True,
                        provenance={"tool": "splat4d train", "preset": self.cfg.preset}, training=training,
                        views=[DatasetView(relative_name(v.name, self.ds.root), v.camera, v.time)
                               for v in self.ds.train])
        state = {"step": self.step, "optimizer": self.optimizer.state_dict(), "generator": self.generator.get_state(),
                 "losses": self.losses, "strategy": {k: v.cpu() for k, v in self.strategy_state.items()}}
        with atomic_path(state_path(self.out), force=True) as tmp:
            torch.save(state, tmp)

    def run(self, stop_at: int | None = None) -> TrainResult:
        from tqdm import tqdm

        cfg = self.cfg
        end = cfg.iters if stop_at is None else min(stop_at, cfg.iters)
        start_time = time.perf_counter()
        bar = tqdm(total=cfg.iters, initial=self.step, unit="it", desc="train", disable=not self.progress,
                   dynamic_ncols=True)
        ema_psnr = None
        try:
            while self.step < end:
                loss, p = self.train_step()
                self.losses.append(loss)
                ema_psnr = p if ema_psnr is None else 0.9 * ema_psnr + 0.1 * p
                bar.update(1)
                bar.set_postfix(loss=f"{loss:.4f}", psnr=f"{ema_psnr:.2f}", n=f"{len(self.params['means']):,}",
                                refresh=False)
                if cfg.checkpoint_every and self.step % cfg.checkpoint_every == 0 and self.step < end:
                    self.save()
        except KeyboardInterrupt:
            bar.close()
            self.save()
            raise
        bar.close()
        self.save()
        return TrainResult(self.out, self.step, time.perf_counter() - start_time, len(self.params["means"]),
                           ema_psnr or float("nan"), self.losses)

    def evaluate_test(self) -> dict | None:
        if not self.ds.test:
            return None
        return evaluate(self.model().detach(), self.ds.test, self.ds.background, self.device,
                        progress=self.progress)
