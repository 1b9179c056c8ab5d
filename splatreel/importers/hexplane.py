"""The HexPlane + MLP deformation field of 4DGaussians (hustvl) and 4DGen (VITA-Group), re-implemented in torch.

Written from the architecture and state-dict keys of hustvl/4DGaussians ``scene/deformation.py`` and
``scene/hexplane.py`` (Wu et al. 2024, "4D Gaussian Splatting for Real-Time Dynamic Scene Rendering") and of
VITA-Group/4DGen's variant of the same files; no upstream code. A `DeformationField` is parsed from a
``deformation.pth`` state dict; `deform` moves raw canonical Gaussians to time t.

Forward pass for a Gaussian at canonical position xyz and time t::

    p = (xyz - aabb[0]) * 2 / (aabb[1] - aabb[0]) - 1     # aabb row 0 is the MAX: every axis is flipped
    q = (p_x, p_y, p_z, t)                                # t used raw (t in [0, 1] reads the upper time rows)
    per level l, plane (a, b) in (x,y) (x,z) (x,t) (y,z) (y,t) (z,t):
        s = bilinear sample of grids.l.p [C, H, W] at u = q[a] (along W), v = q[b] (along H),
            align_corners, border clamping
        4DGaussians: product of the six samples ('mul'); 4DGen: concatenation ('cat'); levels concatenated
    h = feature_out(features)                             # Linear, then (ReLU, Linear) x (depth - 1)
    head(h) = Linear_out(ReLU(Linear_hidden(ReLU(h))))
    xyz' = xyz + head_pos, log_scale' = log_scale + head_scale, q' = q + head_rot (raw, additive),
    opacity' = logit + head_opacity, SH' = SH + head_shs (4DGaussians), dc' = dc + tanh(head_color) (4DGen)

Which heads apply is not in the state dict: it comes from ``cfg_args`` (`DeformFlags`).
"""

from __future__ import annotations

import itertools
import re
from dataclasses import dataclass, field
from typing import Literal

import torch
import torch.nn.functional as F
from torch import Tensor

from .. import quaternion
from ..errors import CheckpointError

#: Coordinate pairs of the six planes, in state-dict order (itertools.combinations of x, y, z, t).
PLANE_AXES: tuple[tuple[int, int], ...] = tuple(itertools.combinations(range(4), 2))
Variant = Literal["4dgaussians", "4dgen"]
Merge = Literal["mul", "cat", "plus"]
_PREFIX = "deformation_net."


@dataclass
class Linear:
    weight: Tensor  # [out, in]
    bias: Tensor  # [out]

    def __call__(self, x: Tensor) -> Tensor:
        return F.linear(x, self.weight, self.bias)


@dataclass
class DeformFlags:
    """Which deformation heads are applied (the ``no_*`` flags of the trainers, inverted)."""

    position: bool = True
    scale: bool = True
    rotation: bool = True
    opacity: bool = False
    color: bool = False  # 4DGaussians: all SH coefficients (shs_deform); 4DGen: the DC term (color_deform)
    quaternion_product: bool = False  # 4DGaussians apply_rotation: q' = normalize(q * dq) instead of q + dq

    @classmethod
    def from_cfg(cls, variant: Variant, cfg: dict) -> tuple["DeformFlags", list[str]]:
        """Flags from parsed cfg_args; the names of the flags that were missing (defaults used)."""
        if variant == "4dgaussians":
            defaults = {"no_dx": False, "no_ds": False, "no_dr": False, "no_do": True, "no_dshs": True,
                        "apply_rotation": False}
            color_key = "no_dshs"
        else:  # released 4DGen config (notes B.6); 4DGen always deforms positions
            defaults = {"no_ds": True, "no_dr": False, "no_do": True, "no_dc": True}
            color_key = "no_dc"
        # apply_rotation appeared late in 4DGaussians: its absence is the old behaviour, not an assumption
        missing = [k for k in defaults if not isinstance(cfg.get(k), bool) and k != "apply_rotation"]
        v = {k: cfg[k] if isinstance(cfg.get(k), bool) else d for k, d in defaults.items()}
        return cls(position=not v.get("no_dx", False), scale=not v["no_ds"], rotation=not v["no_dr"],
                   opacity=not v["no_do"], color=not v[color_key],
                   quaternion_product=bool(v.get("apply_rotation", False))), missing

    def describe(self) -> list[str]:
        names = [("position", self.position), ("scale", self.scale), ("rotation", self.rotation),
                 ("opacity", self.opacity), ("colour", self.color)]
        return [n for n, on in names if on]


@dataclass
class DeformationField:
    """A parsed ``deformation.pth``.

    Attributes:
        variant: '4dgaussians' (heads ``<name>.1`` / ``.3``, SH head of 48) or '4dgen' (``fc2`` / ``fc1``,
            colour head with tanh, scale head of 1).
        aabb: ``[2, 3]`` as stored: row 0 the box maximum, row 1 the minimum.
        grids: per level, six planes ``[C, H, W]`` in `PLANE_AXES` order.
        merge: how the six samples of a level combine ('mul' product, 'cat' concatenation, 'plus' sum).
        feature_out: Linear layers, ReLU between consecutive ones, none at the end.
        heads: head name -> (hidden Linear W->W, output Linear W->out).
        flags: which heads apply.
    """

    variant: Variant
    aabb: Tensor
    grids: list[list[Tensor]]
    merge: Merge
    feature_out: list[Linear]
    heads: dict[str, tuple[Linear, Linear]]
    flags: DeformFlags = field(default_factory=DeformFlags)

    @property
    def channels(self) -> int:
        return self.grids[0][0].shape[0]

    @property
    def time_resolution(self) -> int:
        return self.grids[0][2].shape[1]

    def describe(self) -> dict:
        return {"variant": self.variant, "levels": len(self.grids), "channels": self.channels,
                "spatial_resolutions": [g[0].shape[-1] for g in self.grids], "time_resolution": self.time_resolution,
                "merge": self.merge, "width": self.feature_out[-1].weight.shape[0], "depth": len(self.feature_out),
                "aabb_max": [round(float(x), 6) for x in self.aabb[0]],
                "aabb_min": [round(float(x), 6) for x in self.aabb[1]], "deformed": self.flags.describe()}


# --- parsing ----------------------------------------------------------------------------------------------------
_HEADS = {
    "4dgaussians": {"position": "pos_deform", "scale": "scales_deform", "rotation": "rotations_deform",
                    "opacity": "opacity_deform", "color": "shs_deform"},
    "4dgen": {"position": "pos_deform", "scale": "scales_deform", "rotation": "rotations_deform",
              "opacity": "opacity_deform", "color": "color_deform"},
}
_HEAD_LAYERS = {"4dgaussians": ("1", "3"), "4dgen": ("fc2", "fc1")}
_HEAD_OUT = {"4dgaussians": {"position": 3, "scale": 3, "rotation": 4, "opacity": 1, "color": 48},
             "4dgen": {"position": 3, "scale": 1, "rotation": 4, "opacity": 1, "color": 3}}


def detect_variant(state: dict[str, Tensor]) -> Variant:
    if any(k.startswith(_PREFIX + "color_deform.") or ".fc1." in k for k in state):
        return "4dgen"
    if _PREFIX + "pos_deform.1.weight" in state:
        return "4dgaussians"
    raise CheckpointError("not a 4DGaussians/4DGen deformation state dict (no deformation_net.pos_deform "
                          "layers)")


def _tensor(state: dict, key: str, shape: tuple | None = None) -> Tensor:
    if key not in state:
        raise CheckpointError(f"missing state-dict key {key}")
    v = state[key]
    if not isinstance(v, Tensor) or not v.is_floating_point():
        raise CheckpointError(f"{key} should be a float tensor, found {type(v).__name__}")
    v = v.detach().to("cpu", torch.float32)
    if shape is not None and (v.dim() != len(shape) or any(s not in (-1, d) for s, d in zip(shape, v.shape))):
        raise CheckpointError(f"{key} has shape {list(v.shape)}, expected {list(shape)}")
    if not bool(torch.isfinite(v).all()):
        raise CheckpointError(f"{key} contains NaN or infinite values")
    return v


def _linear(state: dict, prefix: str, in_dim: int | None = None, out_dim: int | None = None) -> Linear:
    w = _tensor(state, prefix + ".weight", (out_dim or -1, in_dim or -1))
    return Linear(w, _tensor(state, prefix + ".bias", (w.shape[0],)))


def parse_state_dict(state: dict[str, Tensor], flags: DeformFlags | None = None,
                     merge: Merge | None = None) -> DeformationField:
    """Build a `DeformationField` from a ``deformation.pth`` state dict; CheckpointError on anything unexpected.

    `merge` overrides the plane merge ('plus' cannot be told from 'mul' by shapes; 4DGen's cfg_args says).
    """
    if not isinstance(state, dict):
        raise CheckpointError(f"expected a state dict, found {type(state).__name__}")
    variant = detect_variant(state)
    unsupported = sorted({k.split(".")[1] for k in state if k.startswith(_PREFIX)
                          and k.split(".")[1] in ("static_mlp", "empty_voxel")})
    if unsupported:
        raise CheckpointError(f"the deformation uses {', '.join(unsupported)} (a masked variant), which splatreel "
                              f"does not import")
    aabb = _tensor(state, _PREFIX + "grid.aabb", (2, 3))
    if bool((aabb[0] == aabb[1]).any()):
        raise CheckpointError("deformation_net.grid.aabb has a zero-size axis")
    levels: dict[int, dict[int, Tensor]] = {}
    for key in state:
        m = re.fullmatch(re.escape(_PREFIX) + r"grid\.grids\.(\d+)\.(\d+)", key)
        if m:
            levels.setdefault(int(m.group(1)), {})[int(m.group(2))] = _tensor(state, key, (1, -1, -1, -1))[0]
    if not levels or sorted(levels) != list(range(len(levels))):
        raise CheckpointError("deformation_net.grid.grids.<level>.<plane> planes are missing")
    grids = []
    for lvl in range(len(levels)):
        planes = levels[lvl]
        if sorted(planes) != list(range(6)):
            raise CheckpointError(f"grid level {lvl} should have planes 0..5, found {sorted(planes)}")
        grids.append([planes[p] for p in range(6)])
    channels = grids[0][0].shape[0]
    if any(p.shape[0] != channels for g in grids for p in g):
        raise CheckpointError("grid planes have different channel counts")
    for lvl, g in enumerate(grids):  # plane (a, b) is [C, R_b, R_a]; t rows the same on every plane
        res = [g[0].shape[2], g[0].shape[1], g[1].shape[1], g[2].shape[1]]
        for (a, b), plane in zip(PLANE_AXES, g):
            if tuple(plane.shape[1:]) != (res[b], res[a]):
                raise CheckpointError(f"grid level {lvl} plane {PLANE_AXES.index((a, b))} has shape "
                                      f"{list(plane.shape)}, expected [C, {res[b]}, {res[a]}]")
    layers = sorted(int(m.group(1)) for k in state
                    if (m := re.fullmatch(re.escape(_PREFIX) + r"feature_out\.(\d+)\.weight", k)))
    if not layers or layers != list(range(0, 2 * len(layers), 2)):
        raise CheckpointError("deformation_net.feature_out layers should be numbered 0, 2, 4, ...")
    feature_out = [_linear(state, f"{_PREFIX}feature_out.{i}") for i in layers]
    for prev, nxt in zip(feature_out, feature_out[1:]):
        if nxt.weight.shape[1] != prev.weight.shape[0]:
            raise CheckpointError("deformation_net.feature_out layer sizes do not chain")
    in_dim = feature_out[0].weight.shape[1]
    per_level = channels * len(grids)
    if merge is None:
        if in_dim == per_level:
            merge = "mul"
        elif in_dim == 6 * per_level:
            merge = "cat"
    expected_in = 6 * per_level if merge == "cat" else per_level
    if merge is None or in_dim != expected_in:
        raise CheckpointError(f"deformation_net.feature_out.0 takes {in_dim} inputs; the grid gives "
                              f"{per_level} (product) or {6 * per_level} (concatenation) features; other "
                              f"variants (grid_pe, no_grid) are not supported")
    width = feature_out[-1].weight.shape[0]
    hidden_name, out_name = _HEAD_LAYERS[variant]
    heads = {}
    for head, module in _HEADS[variant].items():
        prefix = f"{_PREFIX}{module}."
        heads[head] = (_linear(state, prefix + hidden_name, width, width),
                       _linear(state, prefix + out_name, width, _HEAD_OUT[variant][head]))
    return DeformationField(variant, aabb, grids, merge, feature_out, heads, flags or DeformFlags())


# --- forward pass -----------------------------------------------------------------------------------------------
def normalize_to_aabb(xyz: Tensor, aabb: Tensor) -> Tensor:
    """``[N, 3]`` -> ``[N, 3]`` grid coordinates, exactly as stored (row 0 max -> -1, row 1 min -> +1)."""
    return (xyz - aabb[0]) * (2.0 / (aabb[1] - aabb[0])) - 1.0


def sample_plane(plane: Tensor, u: Tensor, v: Tensor) -> Tensor:
    """Bilinear samples of a ``[C, H, W]`` plane at ``[N]`` coordinates in [-1, 1] (u along W, v along H),
    corners aligned, clamped at the border. Returns ``[N, C]``."""
    grid = torch.stack([u, v], -1)[None, None]  # [1, 1, N, 2]
    out = F.grid_sample(plane[None], grid, mode="bilinear", padding_mode="border", align_corners=True)
    return out[0, :, 0].transpose(0, 1)


def plane_samples(field: DeformationField, coords: Tensor, planes: tuple[int, ...]) -> list[list[Tensor]]:
    """Samples ``[N, C]`` of the chosen planes at every level for ``[N, 4]`` coordinates (x̂, ŷ, ẑ, t)."""
    return [[sample_plane(level[p], coords[:, PLANE_AXES[p][0]], coords[:, PLANE_AXES[p][1]]) for p in planes]
            for level in field.grids]


SPACE_PLANES = tuple(i for i, ax in enumerate(PLANE_AXES) if 3 not in ax)  # (0, 1, 3): independent of t
TIME_PLANES = tuple(i for i, ax in enumerate(PLANE_AXES) if 3 in ax)  # (2, 4, 5)


def _combine(field: DeformationField, samples: list[Tensor]) -> Tensor | list[Tensor]:
    if field.merge == "cat":
        return samples
    out = samples[0]
    for s in samples[1:]:
        out = out * s if field.merge == "mul" else out + s
    return out


def space_features(field: DeformationField, xyz: Tensor) -> list:
    """The time-independent part of the HexPlane features of points ``[N, 3]``, per level: the merged samples
    of planes (x,y), (x,z), (y,z) ('mul'/'plus': ``[N, C]``; 'cat': the three ``[N, C]`` samples).

    Pass it to `hexplane_features` to evaluate the same points at many times."""
    coords = torch.cat([normalize_to_aabb(xyz, field.aabb), torch.zeros_like(xyz[:, :1])], -1)
    return [_combine(field, level) for level in plane_samples(field, coords, SPACE_PLANES)]


def hexplane_features(field: DeformationField, xyz: Tensor, t: float, space: list | None = None) -> Tensor:
    """HexPlane features ``[N, F]`` of points ``[N, 3]`` at time `t` (see the module doc).

    Args:
        space: `space_features(field, xyz)`, computed here when None.
    """
    if space is None:
        space = space_features(field, xyz)
    coords = torch.cat([normalize_to_aabb(xyz, field.aabb), torch.full_like(xyz[:, :1], float(t))], -1)
    out = []
    for space_part, time_samples in zip(space, plane_samples(field, coords, TIME_PLANES)):
        if field.merge == "cat":  # plane order 0..5: (x,y) (x,z) (x,t) (y,z) (y,t) (z,t)
            by_plane = dict(zip(SPACE_PLANES, space_part)) | dict(zip(TIME_PLANES, time_samples))
            out.extend(by_plane[p] for p in range(6))
        else:
            out.append(_combine(field, [space_part, *time_samples]))
    return torch.cat(out, -1)


def hidden_state(field: DeformationField, features: Tensor) -> Tensor:
    h = features
    for i, layer in enumerate(field.feature_out):
        h = layer(torch.relu(h) if i > 0 else h)
    return h


def head(field: DeformationField, name: str, h: Tensor) -> Tensor:
    hidden, out = field.heads[name]
    return out(torch.relu(hidden(torch.relu(h))))


@dataclass
class RawGaussians:
    """Raw (pre-activation) Gaussians, as in a 3DGS PLY.

    Attributes:
        means: ``[N, 3]``; log_scales: ``[N, 3]``; quats: ``[N, 4]`` w first, unnormalised;
        opacity_logits: ``[N]``; sh: ``[N, K, 3]``.
    """

    means: Tensor
    log_scales: Tensor
    quats: Tensor
    opacity_logits: Tensor
    sh: Tensor


def deform(field: DeformationField, g: RawGaussians, t: float, space: list | None = None) -> RawGaussians:
    """The raw Gaussians at time `t` (every Gaussian deformed; callers keep static ones themselves).

    `space`: `space_features(field, g.means)`, to reuse across times."""
    h = hidden_state(field, hexplane_features(field, g.means, t, space))
    flags = field.flags
    means = g.means + head(field, "position", h) if flags.position else g.means
    log_scales = g.log_scales + head(field, "scale", h) if flags.scale else g.log_scales  # 4DGen: [N,1] broadcasts
    quats = g.quats
    if flags.rotation:
        dq = head(field, "rotation", h)
        quats = quaternion.normalize(quaternion.multiply(g.quats, dq)) if flags.quaternion_product else g.quats + dq
    opacity = g.opacity_logits
    if flags.opacity and field.variant == "4dgaussians":  # 4DGen's renderer uses the undeformed opacity
        opacity = g.opacity_logits + head(field, "opacity", h)[:, 0]
    sh = g.sh
    if flags.color:
        if field.variant == "4dgaussians":
            sh = g.sh + head(field, "color", h).reshape(-1, 16, 3)
        else:
            sh = torch.cat([g.sh[:, :1] + torch.tanh(head(field, "color", h))[:, None], g.sh[:, 1:]], 1)
    return RawGaussians(means, log_scales, quats, opacity, sh)
