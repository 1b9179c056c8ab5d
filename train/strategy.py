"""Adaptive density control for native 4D Gaussians (clone / split / prune / opacity reset).

The rules are the official 4DGS ones (notes 4dgs-core §3.4). Parameters live in a name -> Parameter dict with one
Adam param group per name; `_edit` applies one change to a parameter and to its Adam moments together, so the two
never drift apart (gsplat's `strategy/ops.py` design).
"""

from __future__ import annotations

import math
from typing import Callable

import torch
from torch import Tensor

from splatreel import covariance

from .config import DensifyConfig

Params = dict[str, torch.nn.Parameter]


def _edit(params: Params, optimizer: torch.optim.Optimizer, fn: Callable[[str, Tensor], Tensor],
          state_fn: Callable[[str, Tensor], Tensor]) -> None:
    """Replace every parameter p by fn(name, p) and its Adam moments m by state_fn(name, m)."""
    for group in optimizer.param_groups:
        name = group["name"]
        old = group["params"][0]
        new = torch.nn.Parameter(fn(name, old.detach()), requires_grad=old.requires_grad)
        state = optimizer.state.pop(old, None)
        if state:
            for key in ("exp_avg", "exp_avg_sq"):
                state[key] = state_fn(name, state[key])
            optimizer.state[new] = state
        group["params"][0] = new
        params[name] = new


def keep(params: Params, optimizer, mask: Tensor) -> None:
    """Keep only the Gaussians where `mask` ``[N]`` holds."""
    _edit(params, optimizer, lambda _, p: p[mask], lambda _, m: m[mask])


def append(params: Params, optimizer, new: dict[str, Tensor]) -> None:
    """Append Gaussians (values per parameter name); their Adam moments start at zero."""
    _edit(params, optimizer, lambda k, p: torch.cat([p, new[k].to(p)]),
          lambda k, m: torch.cat([m, torch.zeros_like(new[k]).to(m)]))


def replace_values(params: Params, optimizer, values: dict[str, Tensor]) -> None:
    """Give the parameters named in `values` new values (same shapes); their Adam moments stay."""
    _edit(params, optimizer, lambda k, p: values[k].to(p) if k in values else p, lambda _, m: m)


def reset_opacity(params: Params, optimizer, value: float = 0.01) -> None:
    """Clamp opacities to at most `value` and zero their Adam moments."""
    cap = math.log(value / (1 - value))

    def fn(k, p):
        return p.clamp(max=cap) if k == "opacity_logits" else p

    def sfn(k, m):
        return torch.zeros_like(m) if k == "opacity_logits" else m
    _edit(params, optimizer, fn, sfn)


def initialize_state(n: int, device) -> dict[str, Tensor]:
    """Running statistics between densification steps."""
    return {"grad_accum": torch.zeros(n, device=device), "count": torch.zeros(n, device=device),
            "max_radii": torch.zeros(n, device=device)}


def accumulate(state: dict[str, Tensor], means2d_grad: Tensor, radii: Tensor, width: int, height: int,
               index: Tensor | None = None) -> None:
    """After backward: add the norm of each visible Gaussian's screen-space mean gradient (in NDC units, as the
    reference: pixel gradients times half the image size) and track the largest screen radius. `index` ``[M]``
    maps the rendered Gaussians to the model's when only some were rendered (default: all, in order)."""
    vis = radii > 0
    rows = vis.nonzero()[:, 0] if index is None else index[vis]
    g = means2d_grad.detach()[vis] * torch.tensor([0.5 * width, 0.5 * height], device=means2d_grad.device)
    state["grad_accum"][rows] += torch.linalg.vector_norm(g, dim=-1)
    state["count"][rows] += 1
    state["max_radii"][rows] = torch.maximum(state["max_radii"][rows], radii[vis].to(state["max_radii"].dtype))


def densify_and_prune(params: Params, optimizer, state: dict[str, Tensor], cfg: DensifyConfig, extent: float,
                      step: int, convention: str, generator: torch.Generator, room: int | None = None
                      ) -> dict:
    """One densification step: clone small / split large high-gradient Gaussians (at most `room` new ones,
    default: up to the cap, highest gradients first), then prune. Returns counts, and ``source`` ``[N']``: the row
    each Gaussian now comes from (itself, or the parent of a clone or a split)."""
    grads = state["grad_accum"] / state["count"].clamp_min(1)
    high = grads >= cfg.grad_threshold
    n = params["means"].shape[0]
    room = max(0, cfg.max_gaussians - n) if room is None else room
    scales = torch.exp(params["log_scales"].detach()).max(-1).values
    clone = high & (scales <= cfg.percent_dense * extent)
    split = high & ~clone
    # respect the cap: fewer new Gaussians than room (a split adds one net)
    if int(clone.sum() + split.sum()) > room:
        order = torch.argsort(grads, descending=True, stable=True)
        allowed = torch.zeros(n, dtype=torch.bool, device=grads.device)
        allowed[order[:room]] = True
        clone, split = clone & allowed, split & allowed
    new: dict[str, list[Tensor]] = {k: [] for k in params}
    if clone.any():
        for k, p in params.items():
            new[k].append(p.detach()[clone])
    if split.any():
        # sample 2 children in 4D from the parent's Gaussian: (xyz, t) = mu + R4 (s * eps), scales / 1.6 (the
        # temporal one too when split in spacetime)
        idx = split.nonzero()[:, 0].repeat(2)
        p = {k: v.detach()[idx] for k, v in params.items()}
        s4 = torch.cat([torch.exp(p["log_scales"]), torch.exp(p["log_t_scales"])[:, None]], -1)
        eps = torch.randn(s4.shape, generator=generator, dtype=s4.dtype, device="cpu").to(s4.device)
        in_time = cfg.split == "spacetime"
        if not in_time:  # children along the parent's spatial axes, at its temporal extent
            eps[:, 3] = 0.0
        r4 = covariance.rotation_4d(p["quats_l"], p["quats_r"], convention)
        offset = (r4 @ (s4 * eps)[..., None])[..., 0]
        p["means"] = p["means"] + offset[:, :3]
        p["t_means"] = p["t_means"] + offset[:, 3]
        p["log_scales"] = p["log_scales"] - math.log(1.6)
        if in_time:
            p["log_t_scales"] = p["log_t_scales"] - math.log(1.6)
        for k in params:
            new[k].append(p[k])
    added = {k: torch.cat(v) for k, v in new.items() if v}
    if added:
        append(params, optimizer, added)
    n_new = params["means"].shape[0] - n
    # prune: the split parents, transparent ones, and (after the first opacity reset) huge ones
    n_all = params["means"].shape[0]
    remove = torch.zeros(n_all, dtype=torch.bool, device=grads.device)
    remove[:n] |= split
    remove |= torch.sigmoid(params["opacity_logits"].detach()) < cfg.prune_opacity
    big = torch.exp(params["log_scales"].detach()).max(-1).values > 0.1 * extent
    if cfg.opacity_reset_every and step > cfg.opacity_reset_every:
        radii = torch.cat([state["max_radii"], torch.zeros(n_new, device=grads.device)])
        remove |= (radii > cfg.prune_screen_radius) | big
    elif not cfg.opacity_reset_every:  # no reset to wait for: huge Gaussians go at once
        remove |= big
    if remove.all():  # never remove everything: keep the most opaque one
        remove[torch.argmax(params["opacity_logits"].detach())] = False
    keep(params, optimizer, ~remove)
    state.update(initialize_state(params["means"].shape[0], grads.device))
    # the row each Gaussian now comes from (itself, or the parent of a clone or split), for per-Gaussian state
    # kept outside the parameters
    parents = [torch.arange(n, device=grads.device), clone.nonzero()[:, 0]]
    if split.any():
        parents.append(idx)
    return {"cloned": int(clone.sum()), "split": int(split.sum()), "pruned": int(remove.sum()),
            "total": int(params["means"].shape[0]), "source": torch.cat(parents)[~remove]}
