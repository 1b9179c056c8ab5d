"""One rigid motion per key frame, fitted by render and compare: when a single set of Gaussians can draw the clip.

Why: the nodes of `train.nodes` move by rigid fits of optical-flow tracks, and a 2D flow falls short of large motions
(on the spinner sample's box, turning 24 degrees a frame, DIS ends 5-14 % short); composed frame after frame the
errors add up, and the tracked nodes ended 19-25 % of the box's size off its true motion at the ends of the clip.
That is harmless while each frame has its own Gaussians (each is carried by the same nodes it was moved to the
canonical frame with), but it keeps one set of Gaussians from drawing every frame, which is what an object that
moves rigidly allows: all the Gaussians then serve every time, and the spinner's held-out views go from 29.5 to 33 dB
in the same 5 minutes. So the middle frame's Gaussians (the template) are carried to the other frames the way
tracking by per-frame optimisation of persistent Gaussians does it (Luiten et al., "Dynamic 3D Gaussians: Tracking
by Persistent Dynamic View Synthesis", 3DV 2024), here with one rigid motion for all the nodes, from the middle frame
outwards:

* each key starts from the previous key's pose moved by the rigid fit of the flow-tracked nodes' motion between the
  two frames;
* a rigid correction (a turn about the template's centre and a shift: 6 parameters) is fitted to that frame's
  training images at about `FIT_SIZE` pixels across by Adam, its rate decaying tenfold.

On the spinner the carried template then stays within 1-2 % of the box's size of the truth at every frame (the
flow's nodes: up to 25 %), for about 10 s of a 5-minute run. How well the carried template draws each frame, beside
how well it draws its own (middle) frame, says whether one set serves the clip (`template_fits`): it does for a rigid
object, not for one whose parts move apart or bend. Where the training images have alpha, that is judged by the
silhouette (the mean absolute alpha error), not the colour: a rigid object lit by a light fixed in the world changes
its shading as it turns, which no rigid motion of fixed colours draws, and the colour ratio grows as the template
sharpens (the spinner's: 1.09 at 130 steps, 1.31 at 499, 1.42 in a 5-minute run that was refused for it; 1.35 with
the box's exact poses), while its silhouette ratio stays near 1 (1.04-1.07) and the bending samples' reach 3.2-8.7.
The template is held to itself rather than to each frame's own Gaussians because those are a shifting yardstick:
early in a run the middle frame's opaque Gaussians are few (on the spinner at a third of the usual steps the template
drew its own frame 2.5 times worse than the frame's slice, and was refused for it), and on a deforming subject the
slice at a key frame also draws its neighbours' Gaussians, which the template leaves out (the wave's template drew
its own frame 0.7 times the slice's error).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import torch

from splatreel import quaternion
from splatreel.datasets import Dataset
from splatreel.model import Gaussians3D, Gaussians4D
from splatreel.pointsets import rigid_fit
from splatreel.rasterize import rasterize
from splatreel.skinned import carry, skin_weights

from .data import downscale_view
from .evaluate import view_target
from .motion import nearest_key
from .nodes import TrackedNodes

#: The fits render the training images downscaled by a whole factor to about this many pixels across (256 px: 1/4).
FIT_SIZE = 64
#: Views drawn per Adam step of a key's fit.
FIT_VIEWS_PER_STEP = 2
#: Adam's rate: radians for the turn, the template's rms radius for the shift (decaying to a tenth over the fit).
FIT_LR = 0.02
#: The template: the Gaussians whose temporal mean is nearest the middle key (the ones kept when it fits,
#: `train.nodes.middle_template`), sliced at the middle frame, those at least this opaque there. All of them, not only
#: the opaque ones: early in a run few are opaque (on the spinner at a third of the usual steps 5 of 3k above 0.3),
#: and a template that draws nothing draws every frame equally badly.
TEMPLATE_OPACITY = 0.01
#: Without alpha: the carried template draws the whole clip when its colour error at every key frame is at most this
#: many times its error at the middle frame (its own). Measured at the flow step of the recipe run for 400 steps: the
#: rigid spinner 1.20 at worst (1.09 when the switch came at a third of the steps); the walker, wave, morph and
#: texture 1.19-1.80 at the first key beside the middle and 1.46-2.37 at the second, 1.6-4.7 at the ends.
TEMPLATE_FIT = 1.4
#: With alpha: the same bound on the silhouette (alpha) error. Measured with the fitted poses at the flow step of the
#: recipe run for 499 steps: the spinner 1.07 at worst (1.04 at 130 steps, 1.07 at 1000); the wave, morph, texture and
#: walker 1.18-2.31 at the keys beside the middle, 1.59-3.67 at the next, 3.2-8.7 at worst. The colour is not held
#: to a bound as well: for a rigid subject under a fixed light its ratio has no ceiling (the spinner's grows as the
#: template sharpens: 1.50 in a 5-minute run), so a subject whose pattern changes inside a still silhouette is taken
#: for one set (`--node-template off` keeps each frame's own).
SILHOUETTE_FIT = 1.5
#: The silhouette is the measure only where the subject leaves this share of the middle frame's pixels transparent
#: (alpha below a half): an alpha that is opaque everywhere draws no silhouette.
MIN_TRANSPARENT = 0.01


@dataclass
class FittedTracks:
    """Nodes moved by the fitted rigid motions, and how well they carry the template.

    Attributes:
        nodes: the nodes, all moving by the fitted rigid motion of each key (`train.nodes.TrackedNodes`).
        template_loss: ``[F]`` mean absolute colour error of the template carried to each key frame, over its views
            (inf at the keys a fit gave up before); at the middle key (``nodes.middle``) its own frame's.
        silhouette_loss: ``[F]`` the same of its alpha, where every training view has alpha and the subject does not
            fill them (the measure `template_fits` judges by); None otherwise.
    """

    nodes: TrackedNodes
    template_loss: np.ndarray
    silhouette_loss: np.ndarray | None = None

    def template_ratio(self) -> float:
        """The worst fitted key's colour error over the template's at its own (middle) frame (keys a fit gave up
        before are left out; inf when none was fitted)."""
        return _worst_ratio(self.template_loss, self.nodes.middle)

    def silhouette_ratio(self) -> float | None:
        """`template_ratio` of the silhouette error; None without one."""
        return None if self.silhouette_loss is None else _worst_ratio(self.silhouette_loss, self.nodes.middle)


def _worst_ratio(loss: np.ndarray, middle: int) -> float:
    fitted = np.isfinite(loss)
    own = loss[middle]
    return float(np.max(loss[fitted]) / max(own, 1e-8)) if fitted.any() and np.isfinite(own) else float("inf")


def _judged(template_loss: np.ndarray, silhouette_loss: np.ndarray | None) -> tuple[np.ndarray, float]:
    """The losses that decide whether one set fits, and their bound: the silhouette's where measured, else the
    colour's."""
    return (template_loss, TEMPLATE_FIT) if silhouette_loss is None else (silhouette_loss, SILHOUETTE_FIT)


def template_fits(fit: FittedTracks) -> bool:
    """Whether the carried template draws every key frame nearly as well as its own: within `SILHOUETTE_FIT` of its
    silhouette error there where the images have alpha, within `TEMPLATE_FIT` of its colour error otherwise."""
    loss, bound = _judged(fit.template_loss, fit.silhouette_loss)
    return bool(np.isfinite(fit.template_loss).all()) and _worst_ratio(loss, fit.nodes.middle) <= bound


def _skew(w: torch.Tensor) -> torch.Tensor:
    z = torch.zeros((), dtype=w.dtype)
    return torch.stack([torch.stack([z, -w[2], w[1]]), torch.stack([w[2], z, -w[0]]),
                        torch.stack([-w[1], w[0], z])])


def _template(model: Gaussians4D, times: list[float], middle: int) -> Gaussians3D:
    with torch.no_grad():
        near = nearest_key(model.t_means, torch.tensor(times))
        s = model.slice(float(times[middle]))
        keep = s.visible & (s.opacities > TEMPLATE_OPACITY) & (near == middle)
    return replace(s.select(keep), velocities=None)  # the nodes move it: no velocity of its own


def _mean_errors(gaussians: Gaussians3D, views: list, background: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Mean absolute (colour, alpha) errors over `views` of (camera, rgb, alpha or None) (alpha: 0 without)."""
    colour = alpha = torch.zeros(())
    for cam, target, target_alpha in views:
        out = rasterize(gaussians, cam, background)
        colour = colour + (out.rgb - target).abs().mean()
        if target_alpha is not None:
            alpha = alpha + (out.alpha - target_alpha).abs().mean()
    return colour / len(views), alpha / len(views)


def _transparent_share(views: list) -> float:
    """The share of the views' pixels whose target alpha is below a half."""
    return float(torch.cat([(alpha < 0.5).flatten() for _, _, alpha in views]).float().mean()) if views else 0.0


def _rigid_start(tracked: TrackedNodes, positions: torch.Tensor, turns: torch.Tensor, k: int, step: int
                 ) -> tuple[torch.Tensor, torch.Tensor]:
    """Key k's poses: key k-step's corrected `positions` ``[M, 3]`` and `turns` ``[M, 3, 3]`` moved by the rigid fit
    of the flow-tracked nodes' motion between the two keys."""
    rot, c0, c1, _ = rigid_fit(tracked.positions[k - step].numpy()[None], tracked.positions[k].numpy()[None])
    rot, c0, c1 = (torch.from_numpy(x[0]) for x in (rot, c0, c1))
    return (positions - c0) @ rot.T + c1, rot @ turns


def fit_tracks(model: Gaussians4D, ds: Dataset, background: torch.Tensor, tracked: TrackedNodes, sigma: float,
               steps: int, seed: int = 0, give_up: bool = False) -> FittedTracks:
    """The rigid motion of `tracked` (the flow's nodes) at every key, corrected by `steps` Adam steps against that
    frame's training images (module doc), as nodes that all move alike; `model` on `ds`'s times. Non-finite flow
    tracks, or a template of fewer than 4 Gaussians, give `tracked` unchanged and an infinite template loss (the
    template does not fit). `give_up`: stop at the first key the template does not fit (`template_fits`; the keys
    not fitted get infinite losses), as a trainer that only wants the template when it fits can: on data that bends,
    the first key or two already tell."""
    rng = np.random.default_rng(seed)
    model = model.detach().to("cpu")
    background = background.detach().cpu().to(torch.float32)
    times = list(ds.frame_times)
    mid = tracked.middle
    tpl = _template(model, times, mid)
    if len(tpl.means) < 4 or not bool(torch.isfinite(tracked.positions).all()):  # nothing to carry, or to start from
        return FittedTracks(tracked, np.full(len(times), np.inf))
    canonical = tracked.canonical.to(torch.float32)
    skin = skin_weights(tpl.means, canonical, sigma)
    radius = float((tpl.means - tpl.means.mean(0)).norm(dim=1).pow(2).mean().sqrt().clamp_min(1e-6))
    rank = {t: k for k, t in enumerate(times)}
    views: list[list] = [[] for _ in times]
    for v in ds.train:
        if v.time in rank:
            small = downscale_view(v, max(1, round(min(v.size) / FIT_SIZE)))
            views[rank[v.time]].append((small.camera, *view_target(small, background)))
    silhouette = all(alpha is not None for vs in views for _, _, alpha in vs) and _transparent_share(views[mid]) \
        >= MIN_TRANSPARENT

    def carried(positions: torch.Tensor, turns: torch.Tensor) -> Gaussians3D:
        means, cov = carry(tpl.means, tpl.covariances, *skin, canonical, positions.to(torch.float32),
                           turns.to(torch.float32))
        return replace(tpl, means=means, covariances=cov)

    positions = tracked.positions.clone()
    turns = quaternion.to_rotmat(quaternion.normalize(tracked.rotations.reshape(-1, 4))).reshape(
        *tracked.rotations.shape[:2], 3, 3)
    template_loss = np.full(len(times), np.inf)
    silhouette_loss = np.full(len(times), np.inf) if silhouette else None
    judged, bound = _judged(template_loss, silhouette_loss)

    def record(k: int) -> None:
        with torch.no_grad():
            colour, alpha = _mean_errors(carried(positions[k], turns[k]), views[k], background)
        template_loss[k] = float(colour)
        if silhouette_loss is not None:
            silhouette_loss[k] = float(alpha)

    record(mid)
    order = [(1, k) for k in range(mid + 1, len(times))] + [(-1, k) for k in range(mid - 1, -1, -1)]
    for step, k in order:
        p0, r0 = _rigid_start(tracked, positions[k - step], turns[k - step], k, step)
        start = carried(p0, r0)
        centre = start.means.mean(0).detach()
        turn = torch.zeros(3, requires_grad=True)
        shift = torch.zeros(3, requires_grad=True)
        opt = torch.optim.Adam([turn, shift], lr=FIT_LR)
        decay = torch.optim.lr_scheduler.LambdaLR(opt, lambda i: 0.1 ** (i / max(steps - 1, 1)))
        for _ in range(steps):
            r = torch.linalg.matrix_exp(_skew(turn))
            moved = replace(start, means=(start.means - centre) @ r.T + centre + radius * shift,
                            covariances=r @ start.covariances @ r.T)
            pick = rng.choice(len(views[k]), min(FIT_VIEWS_PER_STEP, len(views[k])), replace=False)
            loss = _mean_errors(moved, [views[k][j] for j in pick], background)[0]
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            decay.step()
        with torch.no_grad():
            r = torch.linalg.matrix_exp(_skew(turn)).to(positions.dtype)
            c = centre.to(positions.dtype)
            positions[k] = (p0 - c) @ r.T + c + radius * shift.to(positions.dtype)
            turns[k] = r @ r0
        record(k)
        if give_up and judged[k] > bound * max(judged[mid], 1e-8):
            break
    rotations = quaternion.from_rotmat(turns.reshape(-1, 3, 3)).reshape(tracked.rotations.shape)
    return FittedTracks(TrackedNodes(positions, rotations, mid), template_loss, silhouette_loss)
