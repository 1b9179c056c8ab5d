"""Baking a model into keyframes: `KeyframedGaussians` that reproduce ``model.slice(t)`` at chosen key times.

For consumers that know only the closed-form motion of native 4D Gaussians and the keys of a keyframed model: a
model whose motion is neither, such as skinned Gaussians (`splatreel.skinned.SkinnedGaussians`, carried by control
nodes as in SC-GS, Huang et al., CVPR 2024), can be handed to them as its keys. (The viewer and the web player carry
skinned Gaussians themselves; nothing in the package bakes them any more, the Python API still can.)
`bake_keyframes` works for any model with ``slice(t)``; at each key time it stores

* the slice's means;
* the scales and rotations of its covariances (`splatreel.covariance.decompose_covariance_3d`), each rotation
  made the one of its equivalent forms nearest the previous key's (`splatreel.covariance.nearest_equivalent`);
* its opacities, 0 where the slice does not draw the Gaussian (`KeyframedGaussians` marks an absent Gaussian so);
* its colour with the time terms summed at that time (`Gaussians3D.sh`).

Between keys a keyframed model interpolates linearly (slerp for rotations), so a Gaussian on an arc would cut its
chords, and one that fades in and out between two keys is missed. `skinned_bake_times` therefore bakes a skinned
model at its node key times **and the mid-points between them** (2F - 1 keys from F): the baked path passes
through the Catmull-Rom spline half-way through every segment, where a chord is farthest from the arc. The ends of
the model's time range are added where the node keys stop short of them, since the temporal opacity still changes
there.
"""

from __future__ import annotations

import torch
from torch import Tensor

from .covariance import decompose_covariance_3d, nearest_equivalent
from .model import KeyframedGaussians

def bake_keyframes(model, times) -> KeyframedGaussians:
    """`KeyframedGaussians` whose keys are ``model.slice(t)`` at each of `times` (strictly increasing), in the model's
    dtype on the CPU (see module doc). Any model with ``slice(t)`` and ``sh_degree``."""
    times = [float(t) for t in times]
    keys = {"means": [], "quats": [], "scales": [], "opacities": [], "sh": []}
    with torch.no_grad():
        for t in times:
            g = model.slice(t)
            scales, quats = decompose_covariance_3d(g.covariances.double())
            if keys["quats"]:
                quats = nearest_equivalent(quats, keys["quats"][-1].double())
            dtype = g.means.dtype
            keys["means"].append(g.means.detach().cpu())
            keys["quats"].append(quats.to("cpu", dtype))
            keys["scales"].append(scales.to("cpu", dtype))
            keys["opacities"].append(torch.where(g.visible, g.opacities, torch.zeros_like(g.opacities)).cpu())
            keys["sh"].append(g.sh.detach().cpu())
        stacked = {k: torch.stack(v) for k, v in keys.items()}
    return KeyframedGaussians(times=torch.tensor(times, dtype=stacked["means"].dtype), sh_degree=int(model.sh_degree),
                              **stacked)


def keys_and_midpoints(keys, time_range: tuple[float, float]) -> list[float]:
    """Key times `keys` ``[F]`` (increasing) and the mid-point between each pair (2F - 1 times), with the ends of
    `time_range` added where the keys do not reach them."""
    keys = [float(k) for k in keys]
    times = [keys[0]]
    for a, b in zip(keys, keys[1:]):
        times += [0.5 * (a + b), b]
    t0, t1 = (float(t) for t in time_range)
    return ([t0] if t0 < times[0] else []) + times + ([t1] if t1 > times[-1] else [])


def skinned_bake_times(model) -> list[float]:
    """The times `bake_keyframes` bakes a skinned model at: its node key times and their mid-points (module doc)."""
    return keys_and_midpoints(model.node_times.tolist(), model.time_range)
