"""The flow step: once in a run (config ``flow_motion_at``), the optical flow of the training videos sets the motion.

What it sets depends on ``motion`` (`train.config.MOTIONS`):

* linear, quadratic: every Gaussian a camera saw gets its velocity from the flow (`train.motion`);
* nodes: control nodes, each tracked by its neighbours' flow, carry the Gaussians from then on (`train.nodes`), each
  frame's own; with one camera per time (no flow) the nodes are tracked by the model's own motion, and the groups it
  loses are followed by their colour in the images (`train.colour_tracks`, config ``colour_tracks``);
* auto: the nodes move by one rigid motion per key frame, fitted to the frames' images (`train.pose_fit`). Where that
  carries the middle frame's Gaussians to every frame, those alone draw the clip, static in time, carried by the
  nodes; elsewhere the velocities as for linear/quadratic.

`flow_step` decides and computes; the trainer applies what it returns to its parameters and optimizer.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from splatreel.datasets import Dataset
from splatreel.model import Gaussians4D

from .colour_tracks import follow_lost_groups
from .config import TrainConfig
from .motion import FlowTracks, flow_tracks, flow_velocities, with_velocities
from .nodes import TrackedNodes, middle_template, node_spacing, to_canonical, track_nodes, track_nodes_by_motion
from .pose_fit import fit_tracks, template_fits


#: Fewest Gaussians the one set for the clip may keep; with fewer (nodes out of reach of the middle frame's
#: Gaussians) every frame keeps its own, or with motion 'auto' the motion stays native. A guard: since nodes are no
#: longer drawn twice at one place (`splatreel.pointsets.farthest_point_subset`), no run has come near it.
MIN_TEMPLATE = 4


@dataclass
class FlowStep:
    """What the flow step changes.

    Attributes:
        values: new values of trained tensors for every Gaussian (the flow's velocities folded into each 4D shape,
            or the Gaussians moved to the nodes' canonical frame); empty when nothing changes.
        count: Gaussians a camera saw (velocities), or nodes that carry the Gaussians from now on; 0: nothing changed.
        nodes: the tracked nodes when they carry the Gaussians from now on, and `sigma` their spacing.
        keep: ``[N]`` with one set of Gaussians for the clip, the ones that stay (after `values`), and `kept_values`
            their new (static) temporal means and std-devs.
        outcome: motion nodes and auto: what the switch to nodes decided, ``{"template": bool, "template_ratio":
            float | None, "silhouette_ratio": float | None}`` (`Trainer.node_outcome`; the ratios of
            `train.pose_fit.FittedTracks`, None when not measured), with one camera per time also ``"tracked_by": "motion"`` and
            with `TrainConfig.colour_tracks` ``"colour_tracks"`` (`train.colour_tracks.ColourTracks.outcome`);
            None when no switch was tried or the data has no videos.
    """

    values: dict[str, torch.Tensor]
    count: int
    nodes: TrackedNodes | None = None
    sigma: float = 0.0
    keep: torch.Tensor | None = None
    kept_values: dict[str, torch.Tensor] | None = None
    outcome: dict | None = None


def _rounded(ratio: float | None) -> float | None:
    """A ratio for the checkpoint's JSON metadata: None for none, or for inf (nothing was fitted)."""
    return round(ratio, 3) if ratio is not None and math.isfinite(ratio) else None


def flow_step(model: Gaussians4D, ds: Dataset, background: torch.Tensor, cfg: TrainConfig,
              time_range: tuple[float, float]) -> FlowStep:
    """The flow step (module doc) for `model` (on the CPU, on `ds`'s times) under `cfg`'s motion."""
    tracks = flow_tracks(model, ds, background) if cfg.motion != "nodes" else None
    outcome = None
    if cfg.motion in ("nodes", "auto"):
        step = _node_step(model, ds, background, cfg, time_range, tracks)
        if step.count or cfg.motion == "nodes":
            return step
        outcome = step.outcome
    velocity, seen = flow_velocities(model, ds, background, tracks)
    return FlowStep(with_velocities(model, velocity, ds.frame_times) if seen else {}, seen, outcome=outcome)


def _node_step(model: Gaussians4D, ds: Dataset, background: torch.Tensor, cfg: TrainConfig,
               time_range: tuple[float, float], tracks: FlowTracks | None) -> FlowStep:
    """Track the control nodes (motion 'nodes': each by its neighbours' fine-flow tracks; 'auto': all by the rigid fit
    of `tracks`), then fit one rigid motion per key to the frames' images: where it carries the middle frame's
    Gaussians to every frame (or ``node_template`` says so), keep only those; otherwise (motion 'nodes') every frame
    keeps its own, carried by the flow's nodes. Nothing changes when the data has no videos to track the nodes in,
    or with motion 'auto' when one set does not fit."""
    auto = cfg.motion == "auto"
    tracked = track_nodes(model, ds, background, cfg.node_count, cfg.seed, tracks=tracks, rigid=auto)
    # no videos (one camera per time): the model's own motion tracks the nodes, and each frame keeps its Gaussians
    by_motion = tracked is None and not auto
    colour = None
    if by_motion:
        tracked = track_nodes_by_motion(model, ds.frame_times, cfg.node_count, cfg.seed)
        if tracked is not None and cfg.colour_tracks:  # the parts it lost, looked for in the images
            found = follow_lost_groups(tracked, ds, background)
            tracked, colour = found.nodes, found.outcome()
    if tracked is None:
        return FlowStep({}, 0)
    sigma = node_spacing(tracked.canonical)
    fit = None
    if cfg.node_fit_steps and cfg.node_template != "off" and not by_motion:
        fit = fit_tracks(model, ds, background, tracked, sigma, cfg.node_fit_steps, cfg.seed,
                         give_up=cfg.node_template == "auto")
    one = not by_motion and (cfg.node_template == "on" or
                             (cfg.node_template == "auto" and fit is not None and template_fits(fit)))
    ratio = None if fit is None else fit.template_ratio()
    silhouette = None if fit is None else fit.silhouette_ratio()
    outcome = {"template": one, "template_ratio": _rounded(ratio), "silhouette_ratio": _rounded(silhouette)}
    if by_motion:
        outcome["tracked_by"] = "motion"
    if colour is not None:
        outcome["colour_tracks"] = colour
    if one and fit is not None:
        tracked = fit.nodes
    if auto and not one:
        return FlowStep({}, 0, outcome=outcome)
    key_times = torch.tensor(ds.frame_times, dtype=torch.float64)
    canonical = to_canonical(model, key_times, tracked, sigma)
    keep = kept = None
    if one:  # the mask on the trained (float32) values, as the trainer holds them
        keep, kept = middle_template(model.t_means.detach().float(), canonical["means"].float(), key_times,
                                     tracked.middle, time_range, tracked.canonical, sigma)
        if int(keep.sum()) < MIN_TEMPLATE:  # degenerate nodes
            outcome = {**outcome, "template": False}
            if auto:
                return FlowStep({}, 0, outcome=outcome)
            keep = kept = None
    return FlowStep(canonical, len(tracked.canonical), tracked, sigma, keep, kept, outcome)
