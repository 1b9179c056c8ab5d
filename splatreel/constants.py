"""Rendering constants shared by the trainer's rasterizer, the GL viewer (injected as GLSL #defines) and exporters.

Each value is defined here once. They are the reference 3DGS / official 4DGS rasterizer constants
(graphdeco-inria/diff-gaussian-rasterization ``cuda_rasterizer/forward.cu`` and ``auxiliary.h``, vendored by
fudan-zvg/4d-gaussian-splatting; gsplat ``gsplat/cuda/_constants.py``), so that a model trained by the official code
renders the same here, and the GL viewer matches the trainer's image.
"""

from __future__ import annotations

#: A Gaussian is skipped at a pixel when its alpha is below this (8-bit invisibility); also the opacity cull.
ALPHA_THRESHOLD: float = 1.0 / 255.0
#: Alpha is clamped to this, so that a single splat never makes a pixel fully opaque (keeps 1/(1-a) finite).
MAX_ALPHA: float = 0.99
#: Front-to-back compositing stops once transmittance would fall below this (= (1 - 0.99)^2).
TRANSMITTANCE_THRESHOLD: float = 1e-4
#: Low-pass filter (in pixels^2) added to both diagonal entries of every projected 2D covariance ("dilation").
#: No opacity compensation is applied (the "classic" mode of gsplat and the Inria/4DGS rasterizer).
EPS2D: float = 0.3
#: Gaussians whose camera-space depth is at or below this are culled (official 4DGS/Inria value).
NEAR_PLANE: float = 0.2
#: Gaussians farther than this are culled.
FAR_PLANE: float = 1e10
#: The EWA Jacobian is evaluated at x/z, y/z clamped to this multiple of the half-FOV tangent (1.3 * tan_fov):
#: Gaussians far outside the frustum get a bounded footprint instead of an exploding one.
FRUSTUM_CLAMP: float = 1.3
#: Screen-space radius of a Gaussian's footprint, in standard deviations of its largest 2D axis.
RADIUS_SIGMAS: float = 3.0
#: Floor under (mid^2 - det) when computing the larger eigenvalue of the 2D covariance (Inria's 0.1).
EIGEN_FLOOR: float = 0.1
#: Tile edge in pixels for binning Gaussians into screen tiles.
TILE_SIZE: int = 16
#: A 4D Gaussian is culled at time t unless its temporal marginal exp(-(t-mu_t)^2 / (2 Sigma_tt)) exceeds this.
TEMPORAL_CULL: float = 0.05

# Names of choices. They live here rather than beside the torch code that uses them so that option parsers
# (the CLI's --help, the import options) read them without importing torch.

#: 4D rotation conventions of `splatreel.covariance.rotation_4d`.
ROTATION_CONVENTIONS: tuple[str, ...] = ("current", "legacy")
#: Temporal fades (`splatreel.covariance.temporal_factor`): "cut" (the reference: the marginal as it is, the
#: Gaussian dropped once it is <= TEMPORAL_CULL, so its opacity jumps from 0.05 of its peak to 0) and "smooth" (the
#: same factor faded to 0 over the marginal's last doubling before the cull, so nothing pops).
TEMPORAL_FADES: tuple[str, ...] = ("cut", "smooth")

#: Name -> value of every constant that the GLSL shaders receive as a `#define`.
GLSL_DEFINES: dict[str, float] = {
    "ALPHA_THRESHOLD": ALPHA_THRESHOLD,
    "MAX_ALPHA": MAX_ALPHA,
    "TRANSMITTANCE_THRESHOLD": TRANSMITTANCE_THRESHOLD,
    "EPS2D": EPS2D,
    "NEAR_PLANE": NEAR_PLANE,
    "FRUSTUM_CLAMP": FRUSTUM_CLAMP,
    "RADIUS_SIGMAS": RADIUS_SIGMAS,
    "EIGEN_FLOOR": EIGEN_FLOOR,
    "TEMPORAL_CULL": TEMPORAL_CULL,
}
