"""A skinned model (`splatreel.skinned.SkinnedGaussians`) in the GL renderer: its native data once, its nodes per time.

Linear blend skinning as in SC-GS (Huang et al., "SC-GS: Sparse-Controlled Gaussian Splatting for Editable Dynamic
Scenes", CVPR 2024). The renderer uploads a skinned model's canonical native 4D Gaussians once, in the layout of a
native model (`splats.from_gaussians4d`), plus each Gaussian's skin (`SkinArrays`: 4 node indices and 4 weights; a
model with fewer than 4 nodes pads with zero weights). Per displayed time the CPU computes only the M node poses
(`splatreel.skinned.node_poses`) and uploads them as a small float texture (`NodeKeys.texels`); the pre-pass
evaluates the native Gaussian at t (temporal opacity, colour) and carries its canonical mean and its covariance by
its nodes (``shaders/splat_skin.glsl``), as `SkinnedGaussians.slice` does.

Node texture: row k holds node k, 4 RGBA texels per pose set: its rotation's rows 0-2 with the position's x, y, z
in w, then its canonical position c_k. Set 0 is the pose at t, sets 1 and 2 at t - h and t + h (h = `SPEED_STEP`
of the clip, as `SkinnedGaussians.slice`'s velocities), which the speed mode differences.

The CPU sort needs each Gaussian's carried mean and covariance at t as well: `posed` computes them with the
trainer's fused kernel (`splatreel.carrying`, held to `splatreel.skinned.carry` by the tests), without the
``[N, K, 3, 3]`` gathers that make the torch composition cost ~100 ms at 57k Gaussians.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import torch

from splatreel.carrying import carry_forward
from splatreel.skinned import node_poses, padded_skin

#: The central difference step of the speed mode, as a share of the clip (`SkinnedGaussians.slice`'s velocities).
SPEED_STEP = 1e-3
#: Pose sets in the node texture: t, t - h, t + h.
POSE_SETS = 3
#: RGBA texels per node and pose set.
NODE_TEXELS = 4
#: (row, column) of the covariance entries in a `SplatArrays.cov` row (`splats` packs them; here, not there, since
#: splats imports this module).
COV_TRIU = np.array([(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)], np.int64)
#: The column of a `SplatArrays.cov` row at each (row, column) of the 3x3 covariance.
COV_FULL = np.array([[0, 1, 2], [1, 3, 4], [2, 4, 5]], np.int64)


@dataclass(frozen=True, eq=False)
class NodeKeys:
    """A skinned model's control nodes (float64 CPU tensors): canonical positions ``[M, 3]``, key times ``[F]``, key
    positions ``[F, M, 3]`` and rotations ``[F, M, 4]`` (w first, unnormalised), and the speed mode's step h."""

    canonical: torch.Tensor
    times: torch.Tensor
    positions: torch.Tensor
    rotations: torch.Tensor
    step: float

    @classmethod
    def of(cls, model) -> "NodeKeys":
        tensors = (model.node_canonical, model.node_times, model.node_positions, model.node_rotations)
        return cls(*(x.detach().to("cpu", torch.float64) for x in tensors), step=SPEED_STEP * (model.duration or 1.0))

    @property
    def count(self) -> int:
        return self.canonical.shape[0]

    def poses(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Every node's position ``[M, 3]`` and rotation matrix ``[M, 3, 3]`` at `t` (float64)."""
        positions, turns = node_poses(self.times, self.positions, self.rotations, float(t))
        return positions.numpy(), turns.numpy()

    def texels(self, t: float) -> np.ndarray:
        """``[M, POSE_SETS * NODE_TEXELS, 4]`` float32: the node texture at `t` (module doc)."""
        out = np.zeros((self.count, POSE_SETS, NODE_TEXELS, 4), np.float32)
        out[:, :, 3, :3] = self.canonical.numpy()[:, None]
        for s, at in enumerate((t, t - self.step, t + self.step)):
            positions, turns = self.poses(at)
            out[:, s, :3, :3] = turns
            out[:, s, :3, 3] = positions
        return out.reshape(self.count, POSE_SETS * NODE_TEXELS, 4)


@dataclass
class SkinArrays:
    """Each Gaussian's skin as the pre-pass reads it: `nodes` ``[N, 4]`` (indices, exact in float32) and `weights`
    ``[N, 4]`` float32, and the model's `keys`."""

    nodes: np.ndarray
    weights: np.ndarray
    keys: NodeKeys

    @classmethod
    def of(cls, model) -> "SkinArrays":
        nodes, weights = (x.detach().to("cpu", torch.float32).numpy() for x in padded_skin(model.skin))
        return cls(nodes, weights, NodeKeys.of(model))

    def select(self, mask: np.ndarray) -> "SkinArrays":
        return replace(self, nodes=self.nodes[mask], weights=self.weights[mask])

    def columns(self) -> np.ndarray:
        """``[N, 8]`` float32: the pre-pass attributes a_skin_nodes, a_skin_weights."""
        return np.concatenate([self.nodes, self.weights], axis=1)


def posed(splats, t: float):
    """`splats` (`SplatArrays`) as the static arrays of their Gaussians at time `t`: a skinned model's means and
    covariances carried by its nodes (motion and accelerations zero, time `t`), for the CPU consumers (the depth
    sort, selection markers). Arrays without a skin are returned as they are."""
    if splats.skin is None:
        return splats
    positions, turns = (x.astype(np.float32) for x in splats.skin.keys.poses(t))
    n = len(splats.mean_t)
    mean_t, cov, carried_cov = splats.mean_t.copy(), splats.cov.copy(), np.empty((n, 3, 3), np.float32)
    carry_forward(np.arange(n), splats.mean_t, splats.cov[:, COV_FULL], splats.skin.nodes, splats.skin.weights,
                  splats.skin.keys.canonical.numpy(), positions, turns, True, mean_t, carried_cov,
                  np.empty((0, 3, 3), np.float32))  # writes the xyz columns of mean_t only; no blend (no backward)
    cov[:, :6] = carried_cov[:, COV_TRIU[:, 0], COV_TRIU[:, 1]]  # opacity and speed stay
    motion = splats.motion.copy()
    motion[:, :3] = 0.0
    return replace(splats, mean_t=mean_t, motion=motion, accel=np.zeros_like(splats.accel), cov=cov, skin=None,
                   time=float(t))
