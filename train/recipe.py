"""The default recipe (preset ``auto``): look at the dataset, then choose the training settings for it.

`read_traits` measures what matters (views per time, whether the alpha holds an open floor or backdrop or a bounded
object, image size, frame count, a point cloud beside the data); `auto_recipe` turns the traits into a
`TrainConfig` plus the list of `Decision`s it took, each with its reason and the option that overrides it, which
``splatreel train`` prints. The choices were measured on the procedural samples of every regime (README, "What the
default recipe decides").
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from .config import TrainConfig, preset

if TYPE_CHECKING:
    from splatreel.datasets import Dataset

# numpy and the dataset readers are imported where they are used: `splatreel train --help` states this module's
# constants, and stays quick without them

#: Layouts whose views come from a video-to-multi-view generator rather than a renderer or a capture.
GENERATED_LAYOUTS = ("efficient4d", "sv4d")
#: Share of the image border that must be opaque (over the training images) for the alpha to hold an open floor
#: or backdrop rather than a bounded object.
OPEN_BORDER_SHARE = 0.25
#: Time budgets in minutes (`TrainConfig.minutes`): an image matrix, and one camera per time.
MATRIX_MINUTES = 5.0
ONE_VIEW_MINUTES = 10.0
#: With one camera per time, the initial temporal std-dev as a share of the clip's frames.
TEMPORAL_STD_CLIP_SHARE = 0.1
#: In an image matrix, the initial temporal std-dev in frame intervals (`TrainConfig.t_scale_init_frames`).
MATRIX_TEMPORAL_STD_FRAMES = 1.0
#: Length of the clip on the trainer's time axis (`TrainConfig.clip_duration`), and how far the rotations' learning
#: rate decays over the run (to this share of its start) so that slow motion stays precise on the stretched axis.
CLIP_DURATION = 5.0
ROTATION_LR_DECAY = 0.1
#: Share of the run at which an image matrix's Gaussians get their velocities from optical flow, and one camera per
#: time's control nodes are tracked by the model's own motion (`TrainConfig.flow_motion_at`): once the coarse-to-fine
#: ramp is over and the geometry of each frame is fitted.
FLOW_MOTION_AT = 0.3
#: With one camera per time, motion 'nodes' keys its learned poses every this many frames
#: (`TrainConfig.node_key_every`): each key is then held by the cameras of the frames around it.
ONE_VIEW_NODE_KEY_EVERY = 8
#: Share of an image matrix's training draws that are frames the flow interpolates half-way between a camera's
#: consecutive frames (`TrainConfig.inbetween_share`).
INBETWEEN_SHARE = 0.25
#: Weight of the anisotropy penalty (`TrainConfig.lambda_scale_ratio`), the same in every regime.
SCALE_RATIO_WEIGHT = 0.1
#: Cap on the Gaussian count (`DensifyConfig.max_gaussians`): this many per pixel that the subject covers in a
#: training image (on average), within these bounds. Within a time budget every Gaussian costs steps (the
#: rasterizer's work grows with the count), and a few hundred steps do not place more than that well.
GAUSSIANS_PER_FOREGROUND_PIXEL = 10
#: The same with one camera per time: each Gaussian is fitted by the few views of its times, and a model with more
#: of them fits each view alone better and the others worse (on the floor sample, 10 minutes, splits in space:
#: 150k 23.65 dB held out, 90k 24.06, 60k 24.44, 40k 24.43).
GAUSSIANS_PER_FOREGROUND_PIXEL_ONE_VIEW = 2.5
MAX_GAUSSIANS_RANGE = (60_000, 150_000)


@dataclass(frozen=True)
class DataTraits:
    """What the recipe reads from a dataset."""

    images: int
    frames: int
    views_per_time: float
    has_alpha: bool
    #: Share of border pixels that are opaque (alpha >= 0.5), over the training images; 1 without alpha.
    border_opaque: float
    width: int
    height: int
    point_cloud: Path | None
    #: The dataset's layout (`splatreel.datasets.LAYOUTS`).
    layout: str = "dnerf"
    #: Mean number of opaque pixels (alpha >= 0.5) per training image; every pixel without alpha. None: unknown.
    foreground_pixels: float | None = None

    @property
    def generated(self) -> bool:
        """Views a multi-view generator made (Efficient4D, SV4D): they disagree with each other in places."""
        return self.layout in GENERATED_LAYOUTS

    @property
    def one_view_per_time(self) -> bool:
        return self.views_per_time < 1.5

    @property
    def open_backdrop(self) -> bool:
        return self.border_opaque >= OPEN_BORDER_SHARE

    @property
    def gaussians_per_pixel(self) -> float:
        """Gaussians the cap allows per opaque pixel of a training image, by regime."""
        return GAUSSIANS_PER_FOREGROUND_PIXEL_ONE_VIEW if self.one_view_per_time else GAUSSIANS_PER_FOREGROUND_PIXEL

    @property
    def max_gaussians(self) -> int:
        """The recipe's cap on the Gaussian count (`gaussians_per_pixel`, within `MAX_GAUSSIANS_RANGE`)."""
        lo, hi = MAX_GAUSSIANS_RANGE
        pixels = self.width * self.height if self.foreground_pixels is None else self.foreground_pixels
        return int(min(max(round(self.gaussians_per_pixel * pixels, -4), lo), hi))


@dataclass(frozen=True)
class Decision:
    """One choice of the recipe: what it set, why, and which option overrides it."""

    what: str
    why: str
    option: str

    def line(self, given: str | None = None, instead: str | None = None) -> str:
        """One line for the user; `given` is the option's value when the command line overrode the decision,
        `instead` another option that replaced it (e.g. '--iters 3000' for the time budget)."""
        if instead is not None:
            tail = f"{instead} given instead"
        elif given is None:
            tail = f"{self.option} to change"
        else:
            tail = f"{self.option} {given} given" if given else f"{self.option} given"
        return f"{self.what} ({self.why}; {tail})"


def opaque_coverage(ds: Dataset) -> tuple[float, float]:
    """(share of the outermost 2% of pixels, each side, that are opaque over the training images: 1 when an image
    has no alpha; mean number of opaque pixels per image: every pixel of an image without alpha). Opaque: alpha
    >= 0.5. One pass over the masks."""
    import numpy as np

    ring_opaque = ring_total = 0
    counts, missing = [], False
    for v in ds.train:
        if v.alpha is None:
            missing = True
            counts.append(v.size[0] * v.size[1])
            continue
        h, w = v.alpha.shape
        opaque = v.alpha >= 128
        b = max(1, round(0.02 * min(w, h)))
        counts.append(int(np.count_nonzero(opaque)))
        ring_opaque += counts[-1] - int(np.count_nonzero(opaque[b:h - b, b:w - b]))
        ring_total += w * h - max(h - 2 * b, 0) * max(w - 2 * b, 0)
    return (1.0 if missing else ring_opaque / max(ring_total, 1)), float(np.mean(counts))


def read_traits(ds: Dataset) -> DataTraits:
    from .points import find_point_cloud

    w, h = ds.train[0].size
    border_opaque, foreground_pixels = opaque_coverage(ds)
    return DataTraits(images=len(ds.train), frames=len(ds.frame_times),
                      views_per_time=len(ds.train) / max(len(ds.frame_times), 1),
                      has_alpha=any(v.alpha is not None for v in ds.train), border_opaque=border_opaque,
                      width=w, height=h, point_cloud=find_point_cloud(Path(ds.root)), layout=ds.layout,
                      foreground_pixels=foreground_pixels)


def auto_recipe(traits: DataTraits) -> tuple[TrainConfig, list[Decision]]:
    """The settings for data with these traits, and the decisions behind them."""
    cfg = preset("efficient4d")
    decisions: list[Decision] = []
    dens = dataclasses.replace(cfg.densify, enabled=True, budget_curve=True, start=50, stop=350, every=25,
                               grad_threshold=5e-6, opacity_reset_every=0, max_gaussians=traits.max_gaussians)
    changes: dict = {"preset": "auto", "densify": dens}
    if traits.one_view_per_time:
        # measured on the floor sample with the trainer's time axis: 3 minutes 22.1 and 22.3 dB held out (SSIM
        # 0.871, 0.877), 10 minutes 22.6 (SSIM 0.902). Before that axis, longer runs fitted each view better and
        # the others worse (8 minutes 19.9, 500 steps 21.1)
        changes.update(minutes=ONE_VIEW_MINUTES)
        decisions.append(Decision(f"one camera per time: {ONE_VIEW_MINUTES:g} minutes",
                                  f"{traits.images} images at {traits.frames} times, each seen once: more steps "
                                  "still gain", "--minutes"))
        # measured on the floor sample (96 frames, 3 minutes): sqrt(3) frames 21.0 dB held out, 10 frames 21.3,
        # 43 frames (the official sqrt(D/5)) 20.3; a share of static Gaussians at init: 0.3 20.9, 0.6 20.1
        t_scale = max(cfg.t_scale_init_frames or 0.0, TEMPORAL_STD_CLIP_SHARE * (traits.frames - 1))
        changes.update(t_scale_init_frames=t_scale)
        # measured on the floor sample in 3 minutes: 2 images per step 20.9 dB held out, 4 images 21.5, 8 images
        # 22.0, 16 images 21.6
        changes.update(batch_size=8)
        decisions.append(Decision("8 images per step", "a step averaged over more cameras and times cannot fit one "
                                  "view alone", "--batch-size"))
        decisions.append(Decision(f"temporal std-dev {t_scale:.1f} frames at init",
                                  "a tenth of the clip: each Gaussian starts seen by several cameras, not only "
                                  "the one of its time", "--t-scale-init"))
        # measured on the floor sample, 10 minutes, seed 0, split in spacetime -> in space: cap 150k 23.25 ->
        # 23.65 dB held out (SSIM 0.901 -> 0.911; median temporal std-dev of the floor's Gaussians at the end 2.8 ->
        # 8.4 frames), cap 90k 23.70 -> 24.06. On image matrices (5 minutes) splitting in time is better: spinner
        # 28.62 -> 28.45, walker 33.37 -> 33.04
        changes["densify"] = dens = dataclasses.replace(dens, split="space")
        decisions.append(Decision("split Gaussians in space only",
                                  "a child as short-lived as the official 4D split makes it is seen by fewer "
                                  "cameras, which cannot place it in depth", "--split"))
    else:
        # measured on the spinner sample in 4 minutes: 1 image per step 20.4 dB held out, 4 images 23.7, 8 images
        # 24.1, 16 images 24.0: fewer, better-averaged steps fit an image matrix better in the same time.
        # 4 -> 5 minutes on the four matrix samples: texture 29.7 -> 30.4, wave 33.5 -> 33.9, morph 31.3 -> 31.1,
        # spinner 24.1 -> 23.8 (run-to-run spread about 0.2 dB)
        changes.update(minutes=MATRIX_MINUTES, batch_size=8)
        decisions.append(Decision(
            f"image matrix: {MATRIX_MINUTES:g} minutes",
            f"{traits.views_per_time:.0f} views per time", "--minutes"))
        if traits.frames > 1:
            # measured on the spinner (5 minutes, held out at in-between times): 25.4 / 25.6 dB without, 26.0 with
            # the velocities set at 30 % of the run (the opaque Gaussians' median speed 0.072 -> 0.089 per frame,
            # the box's surface moves 0.115)
            changes.update(flow_motion_at=FLOW_MOTION_AT)
            decisions.append(Decision(f"velocities from optical flow at {FLOW_MOTION_AT:.0%} of the run",
                                      "each camera films consecutive frames: the flow sees motion larger than a "
                                      "Gaussian, which the images' gradients do not", "--flow-motion-at"))
            # measured (5 minutes, held out; training views at key / in-between times on the spinner): spinner
            # 26.0 -> 26.5 dB (29.2 / 27.4 -> 28.4 / 28.5), morph 31.1-31.3 -> 31.5, texture 30.3-30.6 -> 30.5,
            # wave 33.8-34.0 -> 33.7; weight 0.5 on every other draw: spinner 26.3, key times 28.0
            changes.update(inbetween_share=INBETWEEN_SHARE)
            decisions.append(Decision(f"{INBETWEEN_SHARE:.0%} of the draws are frames interpolated half-way "
                                      "between each camera's consecutive frames",
                                      "the model is played at every time, and key frames alone leave the motion "
                                      "between them free", "--inbetween-share"))
            # measured held out, 5 minutes (steps in brackets), at init 0.35 / 0.5 / 1.0 / Efficient4D's 1.73 frames:
            # spinner 27.10 (2320) / 27.46 (2036) / 27.60 (1654) / 27.10 (1042); texture - / 31.38 (1780) / 31.30
            # (1320) / 30.67-30.99; morph - / 30.39 (1417) / 30.45 (1204) / 30.57 (1176); wave 34.82 at 0.5 (2016),
            # 34.27-34.36 at 1.73. A short run hardly changes the extent a Gaussian starts with, and the fewer are
            # alive at a time, the cheaper a step
            changes.update(t_scale_init_frames=MATRIX_TEMPORAL_STD_FRAMES)
            decisions.append(Decision(f"temporal std-dev {MATRIX_TEMPORAL_STD_FRAMES:g} frame at init",
                                      "every time has its own views: a Gaussian that lives longer blurs what moves, "
                                      "and fewer alive at a time make a step cheaper", "--t-scale-init"))
        decisions.append(Decision("8 images per step", "steps averaged over more views and times fit a matrix "
                                  "better in the same time", "--batch-size"))
    if traits.frames > 1:
        # measured held out: the spinner (5 minutes) linear 27.7-27.8 dB, quadratic 28.5 (28.8 with a rotation
        # velocity as well, left out: the box's true angular velocity scored 28.68 against 28.56 at 1400 steps):
        # a box turning 22.5 degrees per frame moves its faces on arcs; the floor (one camera per time, 10
        # minutes, seeds 0 and 1, each pair in the same hour) linear 22.39 / 22.29, quadratic 23.25 / 23.38: a
        # bouncing ball falls on parabolas, a pendulum swings on an arc, and each Gaussian lives about a tenth of
        # the clip; the walker (not tuned on) linear 32.44, quadratic 33.05 / 33.06
        # measured held out, 5 minutes (2026-11-28): the spinner 28.3 quadratic, 29.5 with nodes tracked by the
        # flow, 32.8-33.1 with one set of Gaussians carried by one rigid motion per frame fitted to the images
        # (`motion` 'auto'); where that set does not draw every frame, auto stays quadratic: wave (template ratio 3.9)
        # 33.4 against 33.7, walker (1.9) 33.6 against 33.2-33.4
        if not traits.one_view_per_time:
            changes.update(motion="auto")
            decisions.append(Decision("quadratic motion (each Gaussian learns an acceleration), then one set of "
                                      "Gaussians for the whole clip if one rigid motion per frame carries the middle "
                                      "frame's to every frame",
                                      "a Gaussian can follow a curved path over its life; a rigid object is then "
                                      "drawn by all the Gaussians at every time instead of a share at each",
                                      "--motion"))
        else:
            # measured held out, one after the other: the floor (10 minutes) quadratic 23.59 dB (SSIM 0.902), nodes
            # keyed every 8 frames 24.53 (0.919); 800 steps 23.63 (0.902) against 24.82 (0.927), keyed every 16
            # 23.53; the walker filmed one camera per time (12 cameras, 96 times, 200 px, 10 minutes; not tuned
            # on) 34.36 (0.992) against 36.90 (0.995)
            changes.update(motion="nodes", flow_motion_at=FLOW_MOTION_AT, node_key_every=ONE_VIEW_NODE_KEY_EVERY)
            decisions.append(Decision(f"quadratic motion until {FLOW_MOTION_AT:.0%} of the run, then control nodes, "
                                      "tracked by the model's own motion, carry the Gaussians",
                                      "what moves together shares one motion, fitted by every camera that sees "
                                      "any of it, where a Gaussian alone is seen by the few cameras of its times",
                                      "--motion"))
            decisions.append(Decision(f"the nodes' poses keyed every {ONE_VIEW_NODE_KEY_EVERY} frames",
                                      "a pose keyed at every frame is fitted by one image and can fake its depth",
                                      "--node-key-every"))
            # measured held out, 800 steps, seeds 0 / 1 / 2: the floor 24.82 / 24.25 / 24.43 dB without, 25.52 /
            # 24.97 / 24.40 with (seeds 0 and 1: the pendulum's nodes 0.73 units off without, 0.12 with; seed 2 had
            # no pinned node join its group); the walker filmed one camera per time takes no group (36.76 either way)
            changes.update(colour_tracks=True)
            decisions.append(Decision("the groups of nodes that the model's motion loses followed by their colour in "
                                      "the images",
                                      "a thin or fast part the model barely draws at the switch moves with what "
                                      "changes against each camera's median image", "--colour-tracks"))
        # measured held out (half-way times), 5 minutes: the clip as 1, 3, 5 and 15 time units scored 24.2, 25.0,
        # 25.4 and 24.7 dB on the spinner; at 5 units with a constant rotation rate texture fell 30.3 -> 28.2 and
        # wave 33.9 -> 32.1; with the rate decaying 10x: spinner 25.4, texture 30.3, wave 33.6, and the floor
        # (one camera per time, 3 minutes) 21.7 -> 22.3
        changes.update(clip_duration=CLIP_DURATION, lr_quats_final=ROTATION_LR_DECAY * cfg.lr_quats)
        decisions.append(Decision(f"trained on a clip {CLIP_DURATION:g} time units long",
                                  "Gaussians then follow fast motion between frames instead of fading out and in; "
                                  "the checkpoint keeps the dataset's times", "--clip-duration"))
    # measured on the texture sample (5 minutes, held out): without it 31.16 / 31.27 dB with 1.98 % of the
    # Gaussians sliced to a ratio above 10:1 (most of them needles), with it 31.25 dB and 0.03 %
    changes.update(lambda_scale_ratio=SCALE_RATIO_WEIGHT)
    decisions.append(Decision(f"anisotropy penalty {SCALE_RATIO_WEIGHT:g} above {cfg.max_scale_ratio:g}:1",
                              "a Gaussian few views support can stretch into a needle that fits them and covers "
                              "the other views", "--scale-ratio-weight"))
    changes["confidence"] = traits.generated
    if traits.generated:
        decisions.append(Decision("Efficient4D's confidence weights on", f"{traits.layout} views are generated and "
                                  "disagree in places", "--no-confidence"))
    if traits.point_cloud is not None:
        changes.update(init="points", init_points=str(traits.point_cloud))
        decisions.append(Decision(f"init from {traits.point_cloud.name}", "the dataset ships a point cloud",
                                  "--init"))
    elif traits.open_backdrop:
        changes.update(init="frustum")
        why = "no alpha" if not traits.has_alpha else \
            f"{100 * traits.border_opaque:.0f}% of the image border is opaque: a floor or backdrop"
        decisions.append(Decision("init over what the cameras see", why, "--init"))
    else:
        changes.update(init="ball")
        decisions.append(Decision("init in a ball carved by the masks", "a bounded object", "--init"))
    if max(traits.width, traits.height) >= 256:
        changes.update(resolution_ramp=((0.1, 4), (0.3, 2)))
        decisions.append(Decision("coarse-to-fine: 1/4 then 1/2 resolution for the first 30%",
                                  f"{traits.width}x{traits.height} images", "--resolution-ramp"))
    # measured held out (the cap, the steps it left, dB), 5 minutes, with the subject's mean opaque pixels per
    # image: spinner (4.4k) 150k 412-516 steps 26.3-26.4, 80k 693 26.9, 60k 747 27.3, 40k (30k at init) 1083 27.5;
    # wave (4.2k) 150k 33.6-34.0, 40k 34.5; texture (6.9k) 150k 30.4-30.6, 80k 30.8, 60k 31.0, 40k 30.7; morph
    # (11.1k) 150k 31.0-31.5, 60k 30.4, 40k 30.1; floor (25.6k; 10 minutes) 150k 22.5-22.7, 60k 22.8 (and see
    # GAUSSIANS_PER_FOREGROUND_PIXEL_ONE_VIEW)
    fg = "no alpha: every pixel counts" if traits.foreground_pixels is None or not traits.has_alpha else \
        f"{traits.foreground_pixels:,.0f} on average"
    decisions.append(Decision(f"densify up to {dens.max_gaussians:,} Gaussians",
                              f"{traits.gaussians_per_pixel:g} per opaque pixel of a training image, {fg}, "
                              f"between {MAX_GAUSSIANS_RANGE[0]:,} and {MAX_GAUSSIANS_RANGE[1]:,}: more would take "
                              "steps from the time budget", "--max-gaussians"))
    cfg = dataclasses.replace(cfg, **changes)
    return cfg, decisions
