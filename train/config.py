"""Training configuration: one dataclass with a comment per field, and the named presets (recipes).

Presets
-------
``efficient4d`` (Efficient4D §4.2 / §5.1 and its released reconstruction settings): 50k Gaussians at random in a
ball, no densification, 500 Adam iterations at batch size 1, loss 0.8 L1 + 0.2 D-SSIM (the paper's 8000/2000) with
the inconsistency-aware confidence weights, plus a mask loss on alpha; SH degree 0; Efficient4D's learning rates.

``full`` (the official 4DGS schedule, notes 4dgs-core §3): densification (clone / split / prune) every 100
iterations from 500 to 15000, opacity reset every 3000, SH degree ramp every 1000 up to (3, 2), 30000 iterations;
every step count is scaled with ``--iters`` (`TrainConfig.scaled`).

Options usable with either: ``static_iters`` (SV4D-style static-to-dynamic: fit the first frame's views with time
frozen, then all frames), ``resolution_ramp`` (train at 1/4 then 1/2 resolution early on), ``smooth_weight``
(temporal smoothness, 4DGen's acceleration penalty adapted to native 4D Gaussians) and ``init_mesh`` (4DGen's
grounded init from a user mesh).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

#: How the Gaussians' means can move (`TrainConfig.motion`).
MOTIONS = ("linear", "quadratic", "nodes", "auto")
#: Whether motion 'nodes' keeps one set of Gaussians for the whole clip (`TrainConfig.node_template`).
NODE_TEMPLATES = ("auto", "on", "off")
#: How densification splits a large Gaussian (`DensifyConfig.split`).
SPLITS = ("spacetime", "space")
#: Share of the run (of its iterations, or of its time budget's) at which far_clip 'auto' reads the clip off the model.
FAR_CLIP_AT = 0.3


@dataclass
class DensifyConfig:
    """Adaptive density control of the official 4DGS code (notes 4dgs-core §3.4)."""

    #: Whether densification and pruning run at all.
    enabled: bool = False
    #: First and last iteration (exclusive) at which densification runs, and its period.
    start: int = 500
    stop: int = 15000
    every: int = 100
    #: Clone or split Gaussians whose average screen-space mean gradient (pixels) is at least this.
    grad_threshold: float = 2e-4
    #: Clone if the largest spatial scale is <= percent_dense * scene extent, else split in two.
    percent_dense: float = 0.01
    #: How a split places its two children: "spacetime" (the official 4DGS rule: drawn from the parent's 4D
    #: Gaussian, every scale the temporal one included divided by 1.6) or "space" (drawn along the parent's spatial
    #: axes only, the temporal scale kept, so the children live as long as the parent and stay seen by as many
    #: cameras).
    split: str = "spacetime"
    #: Remove Gaussians whose opacity falls below this.
    prune_opacity: float = 0.005
    #: After the first opacity reset also prune screen radius > this many pixels and scale > 0.1 extent.
    prune_screen_radius: float = 20.0
    #: Clamp every opacity to 0.01 at this period (0: never).
    opacity_reset_every: int = 3000
    #: Never grow past this many Gaussians (keeps CPU runs bounded).
    max_gaussians: int = 1_000_000
    #: Budgeted growth (Taming 3DGS's budget curve): the allowed count rises linearly from the initial count at
    #: `start` to `max_gaussians` at `stop`, and each step grows the highest-gradient candidates up to it. Off:
    #: the official rule (every candidate above the threshold, as long as the cap allows).
    budget_curve: bool = False


@dataclass
class TrainConfig:
    """Everything a training run depends on (stored in the checkpoint's ``training`` metadata)."""

    #: Name of the preset these settings started from.
    preset: str = "efficient4d"
    #: Optimisation steps (one image per step unless batch_size > 1).
    iters: int = 500
    #: Images per optimisation step (gradients are averaged).
    batch_size: int = 1
    #: Seed of every random choice (init, view order, densification): equal seeds give equal runs.
    seed: int = 0
    #: Number of Gaussians at random initialisation.
    num_gaussians: int = 50_000
    #: Radius of the random init ball around the cameras' look-at centre; None: from the cameras' field of view.
    init_radius: float | None = None
    #: Keep only random init points inside the visual hull of the training masks at their own time (space
    #: carving), so that the Gaussians start where the object is in space-time instead of filling the ball.
    init_carve: bool = True
    #: Where the initial Gaussians go: 'ball' (random in a ball every camera sees, Efficient4D), 'frustum' (the
    #: volume the training cameras see: rays through opaque pixels, for floors and backdrops that leave the ball)
    #: or 'points' (the point cloud file `init_points`, e.g. a dataset's fused.ply). Both random kinds are carved
    #: by the alpha masks when `init_carve`.
    init: str = "ball"
    init_points: str | None = None
    #: Mesh file (anything trimesh reads) to sample coloured surface points from, instead of a random ball.
    init_mesh: str | None = None
    #: Initial temporal std-dev in frame intervals of the training video; None: the official sqrt(D / 5) in the
    #: dataset's time units (D = time span), which is 6.7 frames of a 16-frame video in [0, 1] but 1.7 frames
    #: with Efficient4D's integer timestamps 0..15 (the same formula, different units).
    t_scale_init_frames: float | None = None
    #: Share of the initial Gaussians that start static (temporal std-dev the whole clip, no motion): what does
    #: not move is then fitted by every view together (`initialize.start_static`); 0: none.
    static_share: float = 0.0
    #: Final spatial SH degree (0-3) and time degree (0-2); the full preset ramps up to them.
    sh_degree: int = 0
    sh_degree_t: int = 0
    #: Raise the active SH degree (spatial first, then time) every this many steps (0: start at the final one).
    sh_increase_every: int = 0
    #: 4D rotation convention of the new model.
    rotation_convention: str = "current"
    #: Loss weights: L1 and D-SSIM (Efficient4D's 8000 : 2000), L1 between rendered alpha and the mask.
    lambda_l1: float = 0.8
    lambda_dssim: float = 0.2
    lambda_mask: float = 0.1
    #: Efficient4D's inconsistency-aware confidence weights on the L1 and D-SSIM terms.
    confidence: bool = False
    #: Train on every pixel's alpha as given even where the views contradict each other (`alpha_conflicts`);
    #: by default transparent pixels that contradict surfaces other views see get no loss.
    strict_alpha: bool = False
    #: The far clip the capture's alpha was cut at, a camera depth (`train.far_clip`): 'auto' reads it off the model
    #: at `FAR_CLIP_AT` of the run where the views' alpha disagree, 'none' renders everything, or a number.
    far_clip: str | float = "auto"
    #: Temporal smoothness weight (velocity of each Gaussian against its spatial neighbours'; 0: off).
    smooth_weight: float = 0.0
    #: Static-to-dynamic (SV4D): the first `static_iters` steps fit only the first frame's views, time frozen.
    static_iters: int = 0
    #: Coarse-to-fine resolution: (fraction of iters, downscale) pairs, e.g. ((0.2, 4), (0.5, 2)); empty: off.
    resolution_ramp: tuple[tuple[float, int], ...] = ()
    #: Learning rates (Adam, eps 1e-15). Means decay exponentially from lr_means to lr_means_final; all
    #: position-like rates are multiplied by the scene extent as in the official code.
    lr_means: float = 1.6e-4
    lr_means_final: float = 1.6e-6
    lr_t_means: float = 1.6e-4
    lr_sh_dc: float = 2.5e-3
    lr_sh_rest: float = 1.25e-4
    lr_opacity: float = 0.05
    lr_scales: float = 5e-3
    lr_quats: float = 1e-3
    #: When set, the rotations' rate decays exponentially from lr_quats to this over the run, as the means' does:
    #: on a stretched time axis (`clip_duration`) a small turn of a rotation is a large change of velocity.
    lr_quats_final: float | None = None
    densify: DensifyConfig = field(default_factory=DensifyConfig)
    #: Time budget in minutes (None: run `iters` steps). With a budget the run ends on time and every schedule
    #: (learning-rate decay, resolution ramp, densification window, SH ramp) follows the elapsed share of the
    #: budget: step k of the `iters`-step recipe happens at k / iters of the time.
    minutes: float | None = None
    #: Penalty on spatial scale ratios above `max_scale_ratio` (PhysGaussian's anisotropy regulariser as in
    #: nerfstudio's splatfacto: mean(max(s_max / s_min, r) - r)); 0: off. Fights needles that fit one view.
    lambda_scale_ratio: float = 0.0
    max_scale_ratio: float = 10.0
    #: Length of the clip on the trainer's time axis: the dataset's times are stretched so that the clip spans this
    #: many units while training (the same motion is then a smaller tilt of a 4D Gaussian, `time_axis`); checkpoints
    #: stay on the dataset's times. None: the dataset's own units.
    clip_duration: float | None = None
    #: Share of the run (0-1) at which every Gaussian's velocity is set once from the optical flow between each
    #: camera's consecutive frames, lifted to 3D by the model's depth (`train.motion`); 0: never. Needs cameras that
    #: film consecutive frames (an image matrix), save with motion 'nodes', which then tracks its nodes by the model's
    #: own motion at this share (`train.nodes.track_nodes_by_motion`).
    flow_motion_at: float = 0.0
    #: Share of the images a step draws that are frames interpolated by optical flow half-way between a camera's
    #: consecutive frames (`train.flow`); 0: none. Needs cameras that film consecutive frames.
    inbetween_share: float = 0.0
    #: How the Gaussians' means move: 'linear' (native 4DGS), 'quadratic' (each Gaussian also learns an
    #: acceleration, `Gaussians4D.accelerations`, at `lr_accelerations` times the scene extent, per unit of the
    #: trainer's time axis squared), 'nodes' (quadratic until the flow step, `flow_motion_at`, then carried by
    #: `node_count` control nodes tracked by the optical flow: `splatreel.skinned`, `train.nodes`; with one
    #: camera per time, by the model's own motion) or 'auto' (quadratic until the flow step; then
    #: nodes carrying one set of Gaussians for the whole clip where one rigid motion per frame carries the middle
    #: frame's Gaussians to every frame (`train.pose_fit.template_fits`), else quadratic with the flow's velocities).
    motion: str = "linear"
    lr_accelerations: float = 1.8e-3
    #: Control nodes of motion 'nodes', and the learning rates of their key poses: positions (times the scene
    #: extent) and rotations (quaternion units).
    node_count: int = 512
    lr_node_positions: float = 1e-4
    lr_node_rotations: float = 5e-4
    #: The nodes' learned poses are keyed every this many frames (and at the last), the times between on their
    #: spline (`splatreel.skinned`): with one camera per time a pose keyed at every frame is fitted by one image and
    #: moves to fake its depth; keyed every few frames, each pose is held by the several cameras around it.
    node_key_every: int = 1
    #: With one camera per time, follow the groups of nodes that the model's own motion loses by their colour in the
    #: images (`train.colour_tracks`) at the switch to nodes.
    colour_tracks: bool = False
    #: Weight of the as-rigid-as-possible term between neighbouring nodes (motion 'nodes'; `train.nodes.rigidity`).
    rigidity_weight: float = 0.0
    #: Adam steps of each key's rigid correction against its frame's images once the flow has tracked the nodes
    #: (motion 'nodes'; `train.pose_fit`); 0: the flow's poses as they are.
    node_fit_steps: int = 40
    #: Motion 'nodes': keep only the middle frame's Gaussians, drawn at every time and carried by the nodes, one set
    #: for the whole clip ('on'); never ('off'); or when the nodes carry them to every key frame and they draw it
    #: nearly as well as the middle frame ('auto': `train.pose_fit.template_fits`, by the silhouette where the images
    #: have alpha, by the colour otherwise).
    node_template: str = "auto"
    #: Write a checkpoint every this many steps (0: only at the end and on Ctrl-C).
    checkpoint_every: int = 0
    #: 'auto' (CUDA when available, else CPU), 'cpu' or 'cuda'.
    device: str = "auto"

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "TrainConfig":
        d = dict(d)
        dens = DensifyConfig(**d.pop("densify", {}))
        ramp = tuple(tuple(x) for x in d.pop("resolution_ramp", ()))
        known = {f.name for f in dataclasses.fields(cls)}
        return cls(**{k: v for k, v in d.items() if k in known}, densify=dens, resolution_ramp=ramp)

    def scaled(self, iters: int) -> "TrainConfig":
        """The same recipe over `iters` steps: every schedule step count is scaled by iters / self.iters."""
        f = iters / self.iters
        s = lambda x: max(1, int(round(x * f))) if x else 0  # noqa: E731
        dens = dataclasses.replace(self.densify, start=s(self.densify.start), stop=s(self.densify.stop),
                                   every=s(self.densify.every), opacity_reset_every=s(self.densify.opacity_reset_every))
        return dataclasses.replace(self, iters=iters, sh_increase_every=s(self.sh_increase_every),
                                   static_iters=s(self.static_iters), densify=dens)


def _efficient4d() -> TrainConfig:
    # Efficient4D video.yaml: position lr 1e-3 x spatial_lr_scale 10 -> 2e-5 x 10, t lr 1e-3 x 10, feature 1e-2,
    # opacity 0.05, scaling 5e-3, rotation 5e-3 (notes 4dgs-core §3.9). Our rates are multiplied by the scene
    # extent (~4 for an orbit at radius 2.5), so the values below give the same effective rates.
    return TrainConfig(preset="efficient4d", iters=500, batch_size=4, num_gaussians=50_000, confidence=True,
                       t_scale_init_frames=math.sqrt(3.0),
                       lr_means=2.5e-3, lr_means_final=5e-5, lr_t_means=2.5e-3, lr_sh_dc=1e-2, lr_sh_rest=5e-4,
                       lr_opacity=0.05, lr_scales=5e-3, lr_quats=5e-3)


def _full() -> TrainConfig:
    return TrainConfig(preset="full", iters=30_000, num_gaussians=100_000, sh_degree=3, sh_degree_t=2,
                       sh_increase_every=1000, densify=DensifyConfig(enabled=True), checkpoint_every=1000)


PRESETS = {
    "auto": ("reads the data and decides (printed); densification under a cap, a time budget (--minutes)",
             None),
    "efficient4d": ("Efficient4D: 50k random Gaussians, no densification, 500 iterations, confidence-weighted "
                    "L1 + SSIM", _efficient4d),
    "full": ("official 4DGS schedule: densification, opacity reset, SH ramp to (3, 2), 30000 iterations",
             _full),
}


def preset(name: str) -> TrainConfig:
    from splatreel.errors import SplatreelError

    if name not in PRESETS:
        raise SplatreelError(f"unknown preset {name!r} (expected one of {', '.join(PRESETS)})")
    if PRESETS[name][1] is None:
        raise SplatreelError(f"preset {name!r} reads the dataset: use splatreel.train.recipe.auto_recipe")
    return PRESETS[name][1]()
