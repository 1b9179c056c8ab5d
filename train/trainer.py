"""The training loop: fit a `Gaussians4D` to a `Dataset` with one of the recipes of `config`.

`Trainer` is the stateful edge (parameters, Adam, random generator, densification statistics); everything it calls
is a pure function elsewhere in this package. A run writes ``OUT`` (a splatreel checkpoint) and, beside it,
``OUT.state.pt`` (optimizer moments, random state, iteration) so that ``resume`` continues bit for bit.
"""

from __future__ import annotations

import dataclasses
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import torch
from tqdm import tqdm

from splatreel.cameras import DatasetView
from splatreel.checkpoint import load_checkpoint, save_checkpoint
from splatreel.covariance import alive_at, condition_on_time
from splatreel.datasets import Dataset, DatasetImage
from splatreel.errors import CheckpointError, OutputExistsError, SplatreelError
from splatreel.fileio import atomic_path
from splatreel.model import Gaussians4D
from splatreel.skinned import SkinnedGaussians
from splatreel.rasterize import rasterize

from . import strategy
from .alpha_conflicts import AlphaConflicts, find_alpha_conflicts
from .far_clip import FarClip, estimate_far_clip, initial_far_clip
from .config import FAR_CLIP_AT, MOTIONS, TrainConfig
from .confidence import confidence_maps
from .data import camera_videos, downscale_view, relative_name
from .evaluate import evaluate, target_bytes, target_from_bytes, view_bytes
from .flow import inbetween_views
from .flow_step import flow_step
from .nodes import Nodes, node_keys
from .initialize import (carved_init, default_init_radius, frustum_init, initial_parameters, knn, look_at_centre,
                         mesh_points, point_cloud_init, random_ball, start_static)
from .losses import image_loss, mse, psnr_of_mse, scale_ratio_loss, smoothness_loss
from .schedule import active_sh, scheduled_lrs
from .time_axis import TimeAxis, model_on_dataset_time, model_on_training_time, retimed_dataset

def param_names(cfg: TrainConfig) -> tuple[str, ...]:
    """The model tensors the trainer optimises: the native ones, and the accelerations with quadratic motion."""
    if cfg.motion not in MOTIONS:
        raise SplatreelError(f"unknown motion {cfg.motion!r} (expected {' or '.join(MOTIONS)})")
    return Gaussians4D.TENSORS + (("accelerations",) if cfg.motion != "linear" else ())


class BudgetBar(tqdm):
    """A progress bar of the seconds of a time budget. The time left is the budget less the seconds spent, not
    tqdm's estimate from the rate of progress: that one is meaningless before the first update (a resumed or slow
    set-up showed a negative time left)."""

    def __init__(self, **kwargs) -> None:
        super().__init__(bar_format="{desc}: {percentage:3.0f}%|{bar}| {n:.0f}/{total:.0f} s, {left} left{postfix}",
                         **kwargs)

    @property
    def format_dict(self) -> dict:
        d = super().format_dict
        return {**d, "left": self.format_interval(max(0.0, d["total"] - d["n"]))}


def state_path(out: Path) -> Path:
    """Where the resumable training state of checkpoint `out` lives."""
    return out.with_suffix(".state.pt")


def pick_device(name: str) -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise SplatreelError("--device cuda requested but no CUDA device is available")
    return torch.device(name)


@dataclass
class TrainResult:
    out: Path
    iterations: int
    seconds: float
    n_gaussians: int  # in the checkpoint
    train_psnr: float
    losses: list[float] = field(default_factory=list)
    test: dict | None = None


class Trainer:
    """Holds a run's state; `run` trains to `config.iters` (or `stop_at`), writing checkpoints."""

    def __init__(self, dataset: Dataset, config: TrainConfig, out: str | os.PathLike, resume: bool = False,
                 force: bool = False, progress: bool = True, started: float | None = None):
        self.cfg, self.out, self.progress = config, Path(out), progress
        # the trainer works on its own time axis (time_axis); checkpoints go back to the dataset's times
        self.source = dataset
        self.axis = TimeAxis.for_clip(dataset.time_range, config.clip_duration)
        self.ds = dataset = retimed_dataset(dataset, self.axis)
        self.device = pick_device(config.device)
        self.bg = torch.tensor(dataset.background, dtype=torch.float32, device=self.device)
        _, cam_radius = dataset.camera_centre_and_radius()
        self.extent = 1.1 * max(cam_radius, 1e-3)  # official cameras_extent
        self.time_range = dataset.time_range
        self.generator = torch.Generator().manual_seed(config.seed)
        # a time budget counts the set-up too (from `started`, a time.perf_counter() reading: the command's start)
        self.clock = time.perf_counter() if started is None else started
        self.step_seconds = 0.0  # running mean of a step's duration
        self.elapsed_before = 0.0  # seconds spent by the run before it was resumed
        self.step = 0
        self.losses: list[float] = []
        # the images the steps draw from: the training images, then the in-between frames the flow interpolates
        self.inbetween = inbetween_views(dataset) if config.inbetween_share else []
        self._views_at: dict[int, list[DatasetImage]] = {1: dataset.train + [f.view for f in self.inbetween]}
        self._conf = self._confidence() if config.confidence else {}
        self.alpha_conflicts: AlphaConflicts = find_alpha_conflicts(dataset)
        # per-pixel loss weights of each image of `_views` by (index, downscale factor): see `_loss_weights`
        self._pixel_weight: dict[tuple[int, int], torch.Tensor | None] = {}
        self._bytes: dict[tuple[int, int], tuple[torch.Tensor, torch.Tensor | None]] = {}  # see `_target`
        self.nodes: Nodes | None = None  # motion 'nodes', from the flow step on
        #: motion 'nodes' or 'auto': what the switch to nodes decided (`train.flow_step`), None before it
        self.node_outcome: dict | None = None
        #: the capture's far clip, once known (`find_far_clip`): training and evaluation render with it
        self.far_clip: FarClip | None = initial_far_clip(config.far_clip)
        if resume:
            self._resume()
        else:
            if self.out.exists() and not force:
                raise OutputExistsError(f"{self.out} already exists (use --force to overwrite, or --resume)")
            self._init_params()
        self.strategy_state = strategy.initialize_state(len(self.params["means"]), self.device)
        self._last_vstep = self.vstep()
        if resume and "strategy" in self._loaded_state:
            self.strategy_state = {k: v.to(self.device) for k, v in self._loaded_state["strategy"].items()}
        self._nbr = None
        # a resumed run past the point has had its velocities set already
        self._flow_motion_done = resume and self._flow_motion_due(self.vstep())

    # --- set-up ---------------------------------------------------------------------------------------------
    def _init_params(self) -> None:
        cfg = self.cfg
        t_means = None
        rgb = None
        if cfg.init_mesh:
            points, rgb = mesh_points(cfg.init_mesh, cfg.num_gaussians, cfg.seed)
        elif cfg.init == "points":
            if not cfg.init_points:
                raise SplatreelError("init 'points' needs a point cloud file (--init-points FILE)")
            points, rgb = point_cloud_init(Path(cfg.init_points), cfg.num_gaussians, self.ds, self.generator)
        else:
            centre = look_at_centre(self.ds)
            if cfg.init == "frustum":
                found = frustum_init(cfg.num_gaussians, self.ds, centre, self.generator)
            elif cfg.init == "ball":
                radius = cfg.init_radius or default_init_radius(self.ds, centre)
                found = carved_init(cfg.num_gaussians, radius, centre, self.ds, self.generator) \
                    if cfg.init_carve else None
            else:
                raise SplatreelError(f"unknown init {cfg.init!r} (expected ball, frustum or points)")
            if found is not None:
                points, t_means = found
            else:
                radius = cfg.init_radius or default_init_radius(self.ds, centre)
                points = random_ball(cfg.num_gaussians, radius, centre, self.generator)
        if rgb is None:
            rgb = 0.5 + 0.05 * torch.randn(points.shape, generator=self.generator)
        t_scale = None
        if cfg.t_scale_init_frames:
            times = self.ds.frame_times
            step = (times[-1] - times[0]) / max(len(times) - 1, 1)
            t_scale = cfg.t_scale_init_frames * step
        raw = initial_parameters(points, rgb, self.time_range, cfg.sh_degree, cfg.sh_degree_t, self.generator,
                                 t_scale, t_means)
        if cfg.static_share:
            raw = start_static(raw, cfg.static_share, self.time_range, self.generator)
        self._make_optimizer(raw)
        self.n_initial = len(raw["means"])
        self._loaded_state = {}

    def _make_optimizer(self, raw: dict[str, torch.Tensor]) -> None:
        cfg = self.cfg
        names = param_names(cfg)
        if "accelerations" in names and raw.get("accelerations") is None:  # a fresh run, or a linear checkpoint
            raw = {**raw, "accelerations": torch.zeros_like(raw["means"])}
        self.params = {k: torch.nn.Parameter(raw[k].to(self.device, torch.float32).contiguous()) for k in names}
        lrs = {"t_means": cfg.lr_t_means * self.extent * self.axis.scale,
               "log_scales": cfg.lr_scales, "log_t_scales": cfg.lr_scales, "quats_l": cfg.lr_quats,
               "quats_r": cfg.lr_quats, "opacity_logits": cfg.lr_opacity, "sh_dc": cfg.lr_sh_dc,
               "sh_rest": cfg.lr_sh_rest, "accelerations": cfg.lr_accelerations * self.extent,
               **scheduled_lrs(0, cfg, self.extent)}
        self.optimizer = torch.optim.Adam([{"params": [self.params[k]], "lr": lrs[k], "name": k}
                                           for k in names], lr=0.0, eps=1e-15)

    def _resume(self) -> None:
        sp = state_path(self.out)
        if not self.out.exists() or not sp.exists():
            raise CheckpointError(f"cannot resume: {self.out if not self.out.exists() else sp} not found")
        ck = load_checkpoint(self.out)
        if ck.model.kind not in ("gaussians4d", "skinned"):
            raise CheckpointError(f"{self.out}: cannot resume training of a {ck.model.kind} model")
        try:
            st = torch.load(sp, map_location="cpu", weights_only=True)
        except Exception as exc:
            raise CheckpointError(f"{sp}: unreadable training state ({str(exc).strip().splitlines()[0]})") from None
        # the parameters on the training time axis, stored as they were: a re-timed checkpoint would factor the
        # covariances afresh, and it leaves out the Gaussians the clip never draws, so it would no longer match the
        # optimizer's moments (states written before both were stored fall back on the checkpoint)
        raw = st.get("params") or model_on_training_time(ck.model, self.axis).tensors()
        self._make_optimizer(raw)
        self.optimizer.load_state_dict(st["optimizer"])
        if st.get("nodes"):
            self.nodes = Nodes.from_state(st["nodes"], *self._node_lrs(), self.device)
        self.node_outcome = st.get("node_outcome")
        if st.get("far_clip"):
            self.far_clip = FarClip(**st["far_clip"])
        self.generator.set_state(st["generator"])
        self.step = int(st["step"])
        self.elapsed_before = float(st.get("elapsed", 0.0))
        self.n_initial = int(st.get("n_initial", self.cfg.num_gaussians))
        self.losses = list(st.get("losses", []))
        self._loaded_state = st

    def _confidence(self) -> dict[int, tuple[torch.Tensor, torch.Tensor]]:
        """Confidence maps for every training image whose view has a video of >= 3 frames at consecutive dataset
        times. A camera that sees only every k-th time (one camera per time, cameras taking turns) has no video:
        interpolating its frames k steps apart fails on everything that moves, and would down-weight exactly the
        moving objects."""
        out = {}
        for idx in camera_videos(self.ds):
            if len(idx) < 3:
                continue
            frames = [target_bytes(self.ds.train[i], self.ds.background) for i in idx]
            c_rgb, c_ssim = confidence_maps(frames)
            for i, a, b in zip(idx, c_rgb, c_ssim):
                out[i] = (torch.from_numpy(a).to(self.device), torch.from_numpy(b).to(self.device))
        return out

    # --- one step -------------------------------------------------------------------------------------------
    def model(self) -> Gaussians4D | SkinnedGaussians:
        """The model being trained, on the trainer's own time axis (`self.ds`'s times; see `dataset_model`): native
        4D Gaussians, or once control nodes carry them, skinned ones."""
        native = self.native_model()
        return native if self.nodes is None else self.nodes.skinned(native, self.step)

    def native_model(self) -> Gaussians4D:
        """The native 4D Gaussians being trained (canonical once nodes carry them: their accelerations unused)."""
        cfg = self.cfg
        params = self.params if self.nodes is None else {k: v for k, v in self.params.items() if k != "accelerations"}
        return Gaussians4D(**params, sh_degree=cfg.sh_degree, sh_degree_t=cfg.sh_degree_t,
                           time_range=self.time_range, rotation_convention=cfg.rotation_convention)

    def _node_keys(self) -> list[int]:
        """The frames the nodes' learned poses are keyed at (`train.nodes.node_keys`)."""
        return node_keys(len(self.ds.frame_times), self.cfg.node_key_every)

    def _node_lrs(self) -> tuple[float, float]:
        return self.cfg.lr_node_positions * self.extent, self.cfg.lr_node_rotations

    def dataset_model(self, trained: dict[str, torch.Tensor] | None = None) -> Gaussians4D | SkinnedGaussians:
        """The model on the dataset's times (what the checkpoint holds; `model` is on the trainer's own axis), from
        `trained` (default: the current parameters)."""
        trained = trained or {k: v.detach().cpu() for k, v in self.params.items()}
        if self.nodes is not None:  # carried by the nodes: the accelerations are unused
            trained = {k: v for k, v in trained.items() if k != "accelerations"}
        model = model_on_dataset_time(Gaussians4D(**trained, sh_degree=self.cfg.sh_degree,
                                                  sh_degree_t=self.cfg.sh_degree_t, time_range=self.time_range,
                                                  rotation_convention=self.cfg.rotation_convention), self.axis)
        # Gaussians whose temporal mean drifted out of the clip draw nothing in it: the checkpoint leaves them out
        # (they stay in the resumable state, which resumes the run exactly)
        drawn = model.drawn_in_clip()
        model = model.select(drawn)
        if self.nodes is None:
            return model
        n = self.nodes
        keys = torch.tensor([self.source.frame_times[k] for k in self._node_keys()], dtype=torch.float32)
        skin = n.current_skin(len(drawn))  # the skin the run drew with, not one derived afresh from the means
        return SkinnedGaussians(model, n.canonical.cpu(), keys, n.positions.detach().cpu(),
                                n.rotations.detach().cpu(), n.sigma,
                                skin=None if skin is None else tuple(x.cpu()[drawn] for x in skin))

    def _views(self, factor: int) -> list[DatasetImage]:
        if factor not in self._views_at:
            self._views_at[factor] = [downscale_view(v, factor) for v in self._views(1)]
        return self._views_at[factor]

    def _resolution_factor(self, vstep: float) -> int:
        for frac, k in self.cfg.resolution_ramp:
            if vstep < frac * self.cfg.iters:
                return int(k)
        return 1

    def _pick(self, static: bool = False) -> int:
        """Index into `_views` of the next image, from the run's own generator: an in-between frame with
        probability `inbetween_share`, else a training image (the first frame's only while `static`)."""
        if static:
            first = min(v.frame_id for v in self.ds.train)
            pool = [i for i, v in enumerate(self.ds.train) if v.frame_id == first]
            return pool[int(torch.randint(len(pool), (1,), generator=self.generator))]
        if self.inbetween and float(torch.rand((), generator=self.generator)) < self.cfg.inbetween_share:
            return len(self.ds.train) + int(torch.randint(len(self.inbetween), (1,), generator=self.generator))
        return int(torch.randint(len(self.ds.train), (1,), generator=self.generator))

    def _loss_weights(self, i: int, factor: int) -> tuple[torch.Tensor | None, ...]:
        """Per-pixel weights of image `i` of `_views` at 1/`factor` resolution for the L1, D-SSIM and alpha terms.
        A training image: the confidence maps (full resolution only) times the alpha-conflict weight (0 where the
        image's transparency contradicts the other views, unless `strict_alpha`). An in-between frame: its trust."""
        key = (i, factor)
        if key not in self._pixel_weight:
            if i >= len(self.ds.train):
                w = self.inbetween[i - len(self.ds.train)].trust
            else:  # a far clip explains the conflicts: the images are right as they are, rendered at it
                w = None if self.cfg.strict_alpha or not self.alpha_conflicts.detected or self.far_clip_depth \
                    else self.alpha_conflicts.weight(self.ds.train[i])
            if w is not None and factor > 1:
                import cv2

                w = cv2.resize(w, self._views(factor)[i].size, interpolation=cv2.INTER_AREA)
            self._pixel_weight[key] = None if w is None else torch.from_numpy(w).to(self.device)
        w_pixel = self._pixel_weight[key]
        conf = self._conf.get(i) if factor == 1 else None
        if conf is None:
            return w_pixel, w_pixel, w_pixel
        if w_pixel is None:
            return conf[0], conf[1], None
        return conf[0] * w_pixel, conf[1] * w_pixel, w_pixel

    def train_step(self) -> tuple[float, float]:
        cfg = self.cfg
        v = self.vstep()  # one schedule position for the whole step
        lrs = scheduled_lrs(v, cfg, self.extent)
        for g in self.optimizer.param_groups:
            g["lr"] = lrs.get(g["name"], g["lr"])
        deg, deg_t = active_sh(v, cfg)
        if not self._flow_motion_done and self._flow_motion_due(v):
            self.set_flow_motion()
        if self.far_clip is None and v >= FAR_CLIP_AT * cfg.iters:
            self.find_far_clip()
        factor = self._resolution_factor(v)
        static = v < cfg.static_iters
        losses, errors = [], []  # tensors, read once per step: on a GPU each read waits for the device
        model = self.model()  # the parameters only change at the optimizer step, after the batch
        native = model if self.nodes is None else model.gaussians
        with torch.no_grad():
            var_t = native.covariance_4d()[:, 3, 3]
        for _ in range(cfg.batch_size):
            i = self._pick(static)
            view = self._views(factor)[i]
            target, mask = self._target(i, factor)
            shown = alive_at(view.time, native.t_means.detach(), var_t)
            g = model.slice(view.time, sh_degree_t=deg_t, rows=shown)
            out = rasterize(g, view.camera, self.bg, sh_degree=deg, far_plane=self.far_clip_depth)
            if cfg.densify.enabled:
                out.means2d.retain_grad()
            loss = image_loss(out.rgb, out.alpha, target, mask, cfg.lambda_l1, cfg.lambda_dssim, cfg.lambda_mask,
                              self._loss_weights(i, factor))
            (loss / cfg.batch_size).backward()
            if cfg.densify.enabled and out.means2d.grad is not None:
                strategy.accumulate(self.strategy_state, out.means2d.grad, out.radii, view.camera.width,
                                    view.camera.height, shown)
            losses.append(loss.detach())
            errors.append(mse(out.rgb, target))
        regularisers = self.regularisers(native, static)
        if regularisers is not None:
            regularisers.backward()
            losses.append(regularisers.detach() * cfg.batch_size)
        if static:  # static-to-dynamic: time frozen, q_r tied to q_l (static under the 'current' convention)
            for k in ("t_means", "log_t_scales", "quats_r", "accelerations"):
                if k in self.params:
                    self.params[k].grad = None
        self._maybe_densify()
        self.optimizer.step()
        self.optimizer.zero_grad(set_to_none=True)
        if self.nodes is not None:
            self.nodes.step()
        if static:
            with torch.no_grad():
                self.params["quats_r"].copy_(self.params["quats_l"])
        self.step += 1
        loss_sum, psnr_sum = torch.stack([torch.stack(losses).sum(), psnr_of_mse(torch.stack(errors)).sum()]).tolist()
        return loss_sum / cfg.batch_size, psnr_sum / cfg.batch_size

    def _target(self, i: int, factor: int) -> tuple[torch.Tensor, torch.Tensor | None]:
        """(target RGB, alpha or None) of image `i` of `_views(factor)` as `view_target` makes them. Each image is put
        on the device once, as bytes: on a GPU a copy from host memory each step would wait for the device (on the CPU
        the bytes are the dataset's own arrays, not a copy)."""
        key = (i, factor)
        if key not in self._bytes:
            self._bytes[key] = view_bytes(self._views(factor)[i], self.device)
        return target_from_bytes(*self._bytes[key], self.ds.background)

    def regularisers(self, model: Gaussians4D, static: bool) -> torch.Tensor | None:
        """The step's terms on the Gaussians themselves rather than on an image, once per step (they do not depend
        on the image): motion smoothness between neighbours and the anisotropy penalty, over every Gaussian, and the
        control nodes' rigidity; None when none is on."""
        cfg, terms = self.cfg, []
        if self.nodes is not None and cfg.rigidity_weight:
            terms.append(cfg.rigidity_weight * self.nodes.rigidity())
        if cfg.smooth_weight and not static and self.nodes is None:  # nodes carry the Gaussians: no velocities
            if self._nbr is None or self.step % 100 == 0:
                self._nbr = knn(self.params["means"].detach(), k=8)
            velocities = condition_on_time(model.covariance_4d())[1]
            terms.append(cfg.smooth_weight * smoothness_loss(velocities, *self._nbr))
        if cfg.lambda_scale_ratio and len(self.params["log_scales"]):  # the mean over none would be NaN
            terms.append(cfg.lambda_scale_ratio * scale_ratio_loss(self.params["log_scales"], cfg.max_scale_ratio))
        return sum(terms) if terms else None

    @property
    def far_clip_depth(self) -> float | None:
        """The camera depth the renders are cut at (the capture's far clip), None while there is none."""
        return None if self.far_clip is None else self.far_clip.depth

    def find_far_clip(self) -> FarClip:
        """Decide the capture's far clip, once (`train.far_clip`): with far_clip 'auto' where the views' alpha
        disagree, the depth the model's surfaces say the alpha was cut at (the disagreeing pixels then get their
        loss back); else none."""
        found = FarClip(None)
        if self.cfg.far_clip == "auto" and self.alpha_conflicts.detected and not self.cfg.strict_alpha:
            found = estimate_far_clip(self.model().to("cpu"), self.ds.train, self.bg.cpu())
        self.far_clip = found
        self._pixel_weight.clear()  # the conflicts' weights go where a clip explains them
        return found

    def _flow_motion_due(self, vstep: float) -> bool:
        at = self.cfg.flow_motion_at
        return bool(at) and vstep >= at * self.cfg.iters

    def set_flow_motion(self) -> int:
        """The flow step (`train.flow_step`), once: the flow's velocities, or control nodes that carry the Gaussians
        from now on (with motion 'auto' one set of them for the clip where it fits). Returns how many Gaussians a
        camera saw, or how many nodes carry them (0: the data has no videos, nothing changed)."""
        self._flow_motion_done = True
        step = flow_step(self.model().to("cpu"), self.ds, self.bg.cpu(), self.cfg, self.time_range)
        if step.outcome is not None:
            self.node_outcome = step.outcome
        if step.values:
            strategy.replace_values(self.params, self.optimizer, {k: v.to(self.device) for k, v in step.values.items()})
        if step.keep is not None:  # one set of Gaussians for the clip
            strategy.keep(self.params, self.optimizer, step.keep.to(self.device))
            strategy.replace_values(self.params, self.optimizer,
                                    {k: v.to(self.device) for k, v in step.kept_values.items()})
            self.strategy_state = strategy.initialize_state(len(self.params["means"]), self.device)
            self._nbr = None
        if step.nodes is not None:
            keys = self._node_keys()
            self.nodes = Nodes(torch.tensor(self.ds.frame_times, dtype=torch.float64)[keys], step.nodes.canonical,
                               step.nodes.positions[keys], step.nodes.rotations[keys], step.sigma, *self._node_lrs(),
                               self.device, step.nodes.still)
        return step.count

    def elapsed(self) -> float:
        """Seconds this run has spent, across resumes."""
        return self.elapsed_before + time.perf_counter() - self.clock

    def vstep(self) -> float:
        """Where the run is in its schedule, in steps of the `iters`-step recipe: the step itself, or under a time
        budget the elapsed share of the budget times `iters` (so every schedule stretches to the budget)."""
        if not self.cfg.minutes:
            return float(self.step)
        return self.cfg.iters * min(self.elapsed() / (60.0 * self.cfg.minutes), 1.0)

    def finished(self) -> bool:
        """Whether the recipe is done. Under a time budget, the time to save and to score the test views (about a
        third of a training step per image) is kept out of it, so the command ends on time."""
        if self.cfg.minutes:
            reserve = self.step_seconds * (1 + len(self.ds.test) / (3 * self.cfg.batch_size))
            return self.elapsed() + reserve >= 60.0 * self.cfg.minutes
        return self.step >= self.cfg.iters

    def _maybe_densify(self) -> None:
        d = self.cfg.densify
        if not d.enabled:
            return
        s = self.step + 1
        v = float(s) if not self.cfg.minutes else self.vstep()
        if d.start < v < d.stop and s % d.every == 0:
            room = d.max_gaussians - len(self.params["means"])
            if d.budget_curve:
                share = min(max((v - d.start) / max(d.stop - d.start, 1), 0.0), 1.0)
                target = self.n_initial + share * (d.max_gaussians - self.n_initial)
                room = min(room, int(target) - len(self.params["means"]))
            strategy.densify_and_prune(self.params, self.optimizer, self.strategy_state, d, self.extent, s,
                                       self.cfg.rotation_convention, self.generator, max(room, 0))
            self._nbr = None
        reset = d.opacity_reset_every
        if reset and v < d.stop and int(v // reset) > int(self._last_vstep // reset):
            strategy.reset_opacity(self.params, self.optimizer)
        self._last_vstep = v

    # --- output ---------------------------------------------------------------------------------------------
    def save(self) -> int:
        """Write the checkpoint and the resumable state beside it (both atomically); returns how many Gaussians the
        checkpoint holds."""
        trained = {k: v.detach().cpu() for k, v in self.params.items()}
        model = self.dataset_model(trained)
        found = self.alpha_conflicts
        training = {**self.cfg.to_dict(), "iteration": self.step, "dataset": str(self.ds.root),
                    "layout": self.ds.layout, "background_reason": self.ds.background_reason,
                    "alpha_disagreement": round(found.worst_share, 4) if found.checked else None,
                    "alpha_ignored": bool(found.detected and not self.cfg.strict_alpha), "nodes": self.node_outcome,
                    "far_clip_depth": self.far_clip_depth}
        save_checkpoint(self.out, model, background=self.ds.background, force=True,
                        provenance={"tool": "splatreel train", "preset": self.cfg.preset, "up_axis": self.ds.up},
                        training=training,
                        views=[DatasetView(relative_name(v.name, self.ds.root), v.camera, v.time)
                               for v in self.source.train])
        state = {"step": self.step, "optimizer": self.optimizer.state_dict(), "generator": self.generator.get_state(),
                 "elapsed": self.elapsed(), "n_initial": self.n_initial,
                 "losses": self.losses, "strategy": {k: v.cpu() for k, v in self.strategy_state.items()},
                 "params": trained, "nodes": None if self.nodes is None else self.nodes.state_dict(),
                 "node_outcome": self.node_outcome,
                 "far_clip": None if self.far_clip is None else dataclasses.asdict(self.far_clip)}
        with atomic_path(state_path(self.out), force=True) as tmp:
            torch.save(state, tmp)
        return len(model)

    def run(self, stop_at: int | None = None) -> TrainResult:
        """Train until the recipe's end (its iterations, or its time budget) or iteration `stop_at`, then save."""
        cfg = self.cfg
        start_time = time.perf_counter()
        budget = 60.0 * cfg.minutes if cfg.minutes else None
        if budget:  # a bar of seconds, so it shows the time left
            bar = BudgetBar(total=budget, initial=min(self.elapsed(), budget), unit="s", desc="train",
                            disable=not self.progress, dynamic_ncols=True)
        else:
            bar = tqdm(total=cfg.iters, initial=self.step, unit="it", desc="train", disable=not self.progress,
                       dynamic_ncols=True)
        ema_psnr = None
        try:
            while not self.finished() and (stop_at is None or self.step < stop_at):
                t = time.perf_counter()
                loss, p = self.train_step()
                dt = time.perf_counter() - t
                self.step_seconds = dt if not self.step_seconds else 0.9 * self.step_seconds + 0.1 * dt
                self.losses.append(loss)
                ema_psnr = p if ema_psnr is None else 0.9 * ema_psnr + 0.1 * p
                bar.update(min(self.elapsed(), budget) - bar.n if budget else 1)
                bar.set_postfix(loss=f"{loss:.4f}", psnr=f"{ema_psnr:.2f}", n=f"{len(self.params['means']):,}",
                                **({"it": self.step} if budget else {}), refresh=False)
                if cfg.checkpoint_every and self.step % cfg.checkpoint_every == 0 and not self.finished():
                    self.save()
        except KeyboardInterrupt:
            bar.close()
            self.save()
            raise
        bar.close()
        saved = self.save()
        return TrainResult(self.out, self.step, time.perf_counter() - start_time, saved, ema_psnr or float("nan"),
                           self.losses)

    def evaluate_test(self) -> dict | None:
        """Scores of the model as the checkpoint holds it (on the dataset's times) at the test views."""
        if not self.source.test:
            return None
        return evaluate(self.dataset_model().to(self.device), self.source.test, self.source.background, self.device,
                        progress=self.progress, far_clip=self.far_clip_depth)
