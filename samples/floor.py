"""``floor``: small moving objects above an opaque white floor that runs to the horizon, filmed the D-NeRF way (one
camera per time) with an alpha channel that marks what lies nearer than a far clip, not the objects.

Why this scene exists: some third-party datasets in the D-NeRF layout were rendered with a floor and a far clip,
and their alpha is the renderer's "something is nearer than the far clip" mask. A camera looking straight down
from high above has its whole floor beyond the clip (alpha 0, only the objects are opaque), while cameras around
the scene see the same floor opaque up to the clip and transparent past it and in the sky. The views' alpha
therefore DISAGREES about the floor. That is deliberate: the sample reproduces the regime so that trainers and
tools can be tested on it. Do not "fix" it.

Scene (Blender world, +z up; scene time t in [0, 1], held outside):

* floor: the plane z = ``floor_z``, a square of half-size ``floor_half_size`` (it reaches the horizon of the low
  cameras), white with a faint light-grey tile grid. The grid needs vertex colours, so the central square of
  half-size ``patch_half_size`` (every floor point nearer than the far clip from a side camera lies inside it) is
  tessellated finely; the rest is a few big cells of plain white.
* ball: a beach ball (six coloured wedges, white caps) bouncing across the floor and rolling as it goes.
* box: the ``spinner`` box, scaled down, spinning about a tilted axis while sliding along an arc above the floor.
* pendulum: a thin dark rod (the thin part) swinging a striped bob from a fixed pivot above the scene.

Every object moves by more than its own size over the clip; together they stay within 1.45 of the origin
horizontally and 0.17 apart, and in the frame of every side camera at the default field of view.

Rig: 12 fixed cameras looking at the origin, all with the same square field of view (`FloorConfig.fov`):

* cameras 0-10 (side): distance `SIDE_DISTANCE` (4) from the origin, azimuths ``360 k / 11`` degrees (0 on +x,
  towards +y), elevations spread over 10-45 degrees and interleaved (`side_elevation`), so that low and high
  cameras alternate around the scene;
* camera 11 (top): `TOP_HEIGHT` (6.5) straight above the origin, looking straight down, image up = world +y.

Far clip: `FAR_CLIP` (6.95) for every camera, as a camera-space depth (along the viewing axis: the GL far plane).
The top camera's floor lies at depth 7.0, beyond it; its clip plane is 0.05 above the floor, below every object
but the underside of the bouncing ball where it touches the floor (hidden from above anyway). The side cameras see
the floor near the objects nearer than 6.95, and a far strip of floor past the clip and the sky transparent.

Timeline (D-NeRF's monocular regime): training frame i is at t = i / (frames - 1) and is seen by camera i mod 12
only. Test image 0 is at t = 0 (D-NeRF's loader asserts that every split starts at time 0), seen by camera 6;
test image j > 0 is camera (j + 6) mod 12 at the middle of a training interval (see `test_plan`). Test views are
ordered by time.

Model (`FloorScene.build_model`, what ``build_model("floor")`` and ``splatreel sample floor --model`` build): the
scene's native 4D Gaussians without training, for the training benchmark's upper bound. The moving objects are
built as `splatreel.samples.gaussians` builds an object (one Gaussian per surface point and key-time segment, flat
discs, velocity from the known motion), with thinner, fainter discs (`OBJECT_OPACITY`); the floor is static
Gaussians (velocity 0, temporal std-dev 1000: they never fade), flat discs on a square grid in the floor plane
with the floor mesh's lit vertex colours, laid only where most of the cameras that see a floor point see it nearer
than the far clip (`floor_kept`). The far clip bounds that floor to about 4.1 around the origin, so one uniform
grid covers it (`FLOOR_SHARE` of the model). At the defaults (200k Gaussians at 200 px, 96 key times) the model
scores 24.9 dB PSNR / 0.880 SSIM on white. What limits it: a static floor cannot match the views' disagreeing
alpha (the top test view, whose floor the dataset leaves transparent, scores 19.7 dB; the side views 24.8-26.8),
and at 200 px the rasterizer's fixed 0.3 px^2 dilation spills the objects' silhouettes onto the floor and blurs
the tile lines (400 px, 500k Gaussians: 26.1 dB).
"""

from __future__ import annotations

import math
import os
from dataclasses import asdict, dataclass, replace
from functools import cached_property
from pathlib import Path
from typing import ClassVar

import numpy as np
import torch

from splatreel import __version__
from splatreel.cameras import Camera, look_at_c2w, orbit
from splatreel.datasets.dnerf import clean_number
from splatreel.model import Gaussians4D, static_gaussians4d

from .dataset import GENERATOR_VERSION, SampleView, write_layout
from .gaussians import DISC_THICKNESS, motion_model
from .geometry import Mesh, axis_angle_matrix, grid_faces, mix, points_on_surface, smoothstep, sphere_topology
from .objects import SampleConfigError, SampleObject, Spinner, _clamp_time
from .render import AMBIENT, DIFFUSE, LIGHT_DIR, MeshRenderer, shade

#: Number of fixed cameras: `SIDE_CAMERAS` around the scene, then one straight above it.
NUM_CAMERAS = 12
SIDE_CAMERAS = NUM_CAMERAS - 1
TOP_CAMERA = NUM_CAMERAS - 1
SIDE_DISTANCE = 4.0
SIDE_ELEVATIONS = (10.0, 45.0)
#: Consecutive side cameras step this many elevation levels (of 11): low and high cameras are mixed all around.
ELEVATION_STRIDE = 4
TOP_HEIGHT = 6.5
#: Camera-space depth beyond which nothing is drawn (alpha 0): 0.05 less than the top camera's depth of the floor.
FAR_CLIP = 6.95
DEFAULT_FOV_DEG = 45.0

_BEACH_COLORS = ((0.92, 0.16, 0.14), (0.98, 0.82, 0.10), (0.14, 0.36, 0.90),
                 (0.97, 0.97, 0.95), (0.16, 0.70, 0.30), (0.98, 0.50, 0.08))


@dataclass(frozen=True)
class FloorConfig:
    """How the ``floor`` scene is rendered to a dataset (its camera rig and far clip are fixed: see module doc).

    Attributes:
        frames: training images, one per time ``i / (frames - 1)``, seen by camera ``i mod 12``.
        size: image width = height, pixels.
        test_views: number of test images (0 writes empty test/val splits); 12 or more see every camera.
        fov: horizontal = vertical field of view of every camera, degrees.
    """

    frames: int = 96
    size: int = 200
    test_views: int = 12
    fov: float = DEFAULT_FOV_DEG

    def __post_init__(self) -> None:
        def need(cond: bool, msg: str) -> None:
            if not cond:
                raise SampleConfigError(msg)

        need(NUM_CAMERAS <= self.frames <= 1000,
             f"--time-steps must be {NUM_CAMERAS}..1000 for sample floor (each of its {NUM_CAMERAS} cameras sees one "
             f"frame in turn), got {self.frames}")
        need(8 <= self.size <= 4096, f"--size must be 8..4096 pixels, got {self.size}")
        need(0 <= self.test_views <= 1000, f"--test-views must be 0..1000, got {self.test_views}")
        need(math.isfinite(self.fov) and 10.0 <= self.fov <= 120.0,
             f"--fov must be 10..120 degrees for sample floor, got {self.fov}")


# --- geometry ----------------------------------------------------------------------------------------------------

def concat_meshes(meshes: list[Mesh]) -> Mesh:
    """One mesh holding all of `meshes` (faces re-indexed)."""
    offsets = np.cumsum([0] + [len(m.vertices) for m in meshes[:-1]])
    return Mesh(np.concatenate([m.vertices for m in meshes]),
                np.concatenate([m.faces + o for m, o in zip(meshes, offsets)]).astype(np.int32),
                np.concatenate([m.colors for m in meshes]))


def moved(mesh: Mesh, rotation: np.ndarray, offset) -> Mesh:
    """`mesh` rotated about its local origin, then translated by `offset`."""
    return Mesh(mesh.vertices @ np.asarray(rotation).T + np.asarray(offset, np.float64), mesh.faces, mesh.colors)


def floor_ticks(half_size: float, patch_half_size: float, cell: float) -> np.ndarray:
    """Sorted grid coordinates along one floor axis: every `cell` inside the patch, then cells doubling in size out
    to `half_size` (one tensor-product grid: no T-junctions, so no cracks where fine and coarse cells meet)."""
    n = round(2.0 * patch_half_size / cell)
    fine = np.linspace(-patch_half_size, patch_half_size, n + 1)
    outer, x = [], 2.0 * patch_half_size
    while x < half_size:
        outer.append(x)
        x *= 2.0
    outer.append(half_size)
    outer = np.asarray(outer)
    return np.concatenate([-outer[::-1], fine, outer])


def floor_mesh(z: float, half_size: float, patch_half_size: float, tile: float, cells_per_tile: int) -> Mesh:
    """The floor plane at height `z`, facing +z: white, with light-grey lines every `tile` inside the patch.

    Lines sit on vertices (every `cells_per_tile` cells), so linear colour interpolation draws each as a ramp one
    cell wide on either side. They fade out over the patch's last tile, so the plain coarse cells outside (whose
    vertices would smear a line across a whole cell) meet them evenly.
    """
    ticks = floor_ticks(half_size, patch_half_size, tile / cells_per_tile)
    x, y = (a.ravel() for a in np.meshgrid(ticks, ticks, indexing="ij"))  # x along rows: normals cross(x, y) = +z

    def on_line(c: np.ndarray) -> np.ndarray:
        k = c / tile
        return np.abs(k - np.round(k)) < 0.25 / cells_per_tile

    line = on_line(x) | on_line(y)
    fade = 1.0 - smoothstep(patch_half_size - tile, patch_half_size, np.maximum(np.abs(x), np.abs(y)))
    colors = mix(np.ones((len(x), 3)), (0.84, 0.85, 0.87), line * fade)
    n = len(ticks)
    return Mesh(np.stack([x, y, np.full_like(x, z)], -1), grid_faces(n, n), colors)


def beach_ball_mesh(radius: float, rings: int = 18, segments: int = 36) -> Mesh:
    """A ball centred at its local origin: six coloured wedges around z, white caps at both poles."""
    theta, phi, faces = sphere_topology(rings, segments)
    wedge = np.floor(phi / (2.0 * np.pi) * 6.0).astype(int) % 6
    colors = np.asarray(_BEACH_COLORS)[wedge]
    colors = mix(colors, (0.97, 0.97, 0.95), smoothstep(0.88, 0.93, np.abs(np.cos(theta))))
    verts = radius * np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], -1)
    return Mesh(verts, faces, colors)


def rod_mesh(length: float, radius: float, rings: int = 12, segments: int = 10) -> Mesh:
    """A closed cylinder from the local origin down to ``(0, 0, -length)``, dark grey: the sphere topology with
    every ring at full radius and the poles as the centres of the flat ends."""
    theta, phi, faces = sphere_topology(rings, segments)
    r = radius * np.clip(np.sin(theta) / math.sin(math.pi / rings), 0.0, 1.0)
    # z falls as theta grows (0 at the top end, -length at the bottom), like cos(theta): the sphere's winding holds
    verts = np.stack([r * np.cos(phi), r * np.sin(phi), -length * theta / np.pi], -1)
    return Mesh(verts, faces, np.full((len(verts), 3), 0.22))


# --- the scene ---------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class FloorScene(SampleObject):
    """Three moving objects above a floor plane running to the horizon, for the D-NeRF one-camera-per-time rig
    with far-clip alpha (see module doc). Not an object inside the 0.9 ball: its floor spans 60 x 60."""

    name: ClassVar[str] = "floor"
    description: ClassVar[str] = ("scene: a bouncing ball, a spinning box and a pendulum above a white floor to "
                                  "the horizon; 12 fixed cameras, one per time, alpha = nearer than a far clip")

    floor_z: float = -0.5
    floor_half_size: float = 30.0
    patch_half_size: float = 5.0    # tessellated, tile lines drawn (floor nearer than the far clip: within 4.3)
    tile: float = 0.5
    cells_per_tile: int = 8
    ball_radius: float = 0.33
    ball_path: tuple[float, float, float, float] = (-0.7, -0.78, 0.7, -0.62)  # x, y at t = 0, then at t = 1
    ball_bounce: float = 0.6        # height of the ball's bottom above the floor at the top of a bounce
    ball_bounces: float = 2.5       # bounces (half periods of |sin|) over the clip: on the floor at t = 0
    box_half_extents: tuple[float, float, float] = (0.34, 0.24, 0.17)
    box_offset: tuple[float, float, float] = (0.0, 0.72, 0.2)   # added to the spinner's own arc path
    box_arc: tuple[float, float] = (0.7, 0.3)
    box_turns: float = 1.5
    pivot: tuple[float, float, float] = (0.0, -0.05, 0.7)
    pendulum_length: float = 0.85   # pivot to bob centre
    rod_radius: float = 0.022
    bob_radius: float = 0.16
    swing_deg: float = 50.0         # amplitude
    swings: float = 1.5             # periods over the clip

    @cached_property
    def _floor(self) -> Mesh:
        return floor_mesh(self.floor_z, self.floor_half_size, self.patch_half_size, self.tile, self.cells_per_tile)

    @cached_property
    def _ball(self) -> Mesh:
        return beach_ball_mesh(self.ball_radius)

    @cached_property
    def _box(self) -> Spinner:
        # the spinner's marked box and motion (spin about a tilted axis, arc, bob), smaller
        return Spinner(half_extents=self.box_half_extents, subdivisions=8, spin_turns=self.box_turns,
                       arc=self.box_arc)

    @cached_property
    def _pendulum(self) -> Mesh:
        bob = beach_ball_mesh(self.bob_radius, rings=12, segments=24)
        stripes = smoothstep(-0.3, 0.3, np.cos(4.0 * np.arctan2(bob.vertices[:, 1], bob.vertices[:, 0])))
        bob = Mesh(bob.vertices - [0.0, 0.0, self.pendulum_length], bob.faces,
                   mix(np.tile([0.72, 0.18, 0.78], (len(bob.vertices), 1)), (0.96, 0.96, 0.96), 0.8 * stripes))
        return concat_meshes([rod_mesh(self.pendulum_length, self.rod_radius), bob])

    def ball_center(self, t: float) -> np.ndarray:
        """``(3,)`` the ball's centre: straight across the floor, bouncing (on the floor at t = 0)."""
        t = _clamp_time(t)
        x0, y0, x1, y1 = self.ball_path
        h = self.ball_bounce * abs(math.sin(math.pi * self.ball_bounces * t))
        return np.array([x0 + (x1 - x0) * t, y0 + (y1 - y0) * t, self.floor_z + self.ball_radius + h])

    def ball_rotation(self, t: float) -> np.ndarray:
        """``(3, 3)`` the ball rolls along its path: the turned angle is the distance covered over the radius."""
        x0, y0, x1, y1 = self.ball_path
        direction = np.array([x1 - x0, y1 - y0, 0.0])
        axis = np.cross([0.0, 0.0, 1.0], direction)
        return axis_angle_matrix(axis, np.linalg.norm(direction) * _clamp_time(t) / self.ball_radius)

    def swing(self, t: float) -> float:
        """The pendulum's angle from the vertical, radians (about +y, so the bob swings along x)."""
        return math.radians(self.swing_deg) * math.sin(2.0 * math.pi * self.swings * _clamp_time(t))

    def parts(self, t: float) -> dict[str, Mesh]:
        """The scene's meshes at time t, by name: floor, ball, box, pendulum."""
        return {"floor": self._floor,
                "ball": moved(self._ball, self.ball_rotation(t), self.ball_center(t)),
                "box": moved(self._box.mesh(t), np.eye(3), self.box_offset),
                "pendulum": moved(self._pendulum, axis_angle_matrix((0.0, 1.0, 0.0), self.swing(t)), self.pivot)}

    def mesh(self, t: float) -> Mesh:
        return concat_meshes(list(self.parts(t).values()))

    def objects_mesh(self, t: float) -> Mesh:
        """The moving objects at time t, without the floor."""
        return concat_meshes([m for name, m in self.parts(t).items() if name != "floor"])

    def center(self, t: float) -> np.ndarray:
        """The objects' bounding-box centre (the floor's would be fixed)."""
        lo, hi = self.objects_mesh(t).bounds
        return 0.5 * (lo + hi)

    def floor_ticks(self) -> np.ndarray:
        """The floor mesh's grid coordinates along x and along y (see `floor_ticks`)."""
        return floor_ticks(self.floor_half_size, self.patch_half_size, self.tile / self.cells_per_tile)

    def build_model(self, num_gaussians: int | None = None, frames: int | None = None, seed: int = 0,
                    config: FloorConfig | None = None) -> Gaussians4D:
        """The scene's native 4D Gaussians (what `build_model("floor", ...)` returns): the moving objects as
        `motion_model` builds an object's (thinner, fainter discs: see `OBJECT_OPACITY`), followed by the floor
        as static Gaussians where `config`'s rig sees it nearer than the far clip (`floor_gaussians`).

        Args:
            num_gaussians: Gaussians in all (>= 2; None: `default_model_gaussians`); the floor gets at most
                `FLOOR_SHARE` of them, the objects exactly the rest.
            frames: the objects' key times ``k / (frames - 1)`` (>= 2; None: the dataset's, ``config.frames``).
            seed: the objects' surface sampling seed.
            config: the dataset's rig (its field of view decides which floor is seen); default `FloorConfig()`.
        """
        config = config or FloorConfig()
        if not isinstance(config, FloorConfig):
            raise SampleConfigError(f"sample 'floor' has its own camera rig and takes a FloorConfig, "
                                    f"got {type(config).__name__}")
        total = default_model_gaussians(config) if num_gaussians is None else num_gaussians
        if total < 2:
            raise SampleConfigError(f"the floor scene's model needs num_gaussians >= 2 (objects and floor), "
                                    f"got {total}")
        floor = floor_gaussians(self, max(1, min(round(FLOOR_SHARE * total), total - 1)), config)
        objects = motion_model(self.objects_mesh, total - len(floor), config.frames if frames is None else frames,
                               seed, disc_size=OBJECT_DISC_SIZE, opacity=OBJECT_OPACITY)
        return concat_models([objects, floor])

    def write_dataset(self, out: str | os.PathLike, config: FloorConfig | None = None, force: bool = False,
                      progress: bool = False, renderer: MeshRenderer | None = None) -> Path:
        """Render the scene to a D-NeRF layout folder `out` (atomically): what `write_dataset("floor", ...)` does."""
        if config is None:
            config = FloorConfig()
        if not isinstance(config, FloorConfig):
            raise SampleConfigError(f"sample 'floor' has its own camera rig and takes a FloorConfig, "
                                    f"got {type(config).__name__}")
        train, test = train_views(config), test_views(config)
        return write_layout(out, self, train, test, rig_cameras(config)[0][2],
                            lambda r: sample_json(self, config, r, train, test), far=FAR_CLIP, force=force,
                            progress=progress, renderer=renderer)


# --- exact Gaussian model ---------------------------------------------------------------------------------------

#: Gaussians per image pixel in `FloorScene.build_model` unless told (200k at 200 px), within the bounds below.
#: The best count follows the image size: the rasterizer's fixed dilation in pixels (`splatreel.constants.EPS2D`)
#: makes denser discs spill further past the silhouettes in small images (64 px: 21.3 dB at 20k, 18.6 at 200k),
#: while large images want more (400 px: 25.2 dB at 200k, 26.1 at 500k).
GAUSSIANS_PER_PIXEL = 5
MODEL_GAUSSIANS_RANGE = (20_000, 500_000)
#: Share of the Gaussians that the static floor gets (at most); the moving objects get the rest. The floor's
#: accuracy at 200 px is the same from 15k to 40k floor Gaussians: the compositing order of overlapping discs,
#: not the grid spacing, limits how sharp its tile lines come out.
FLOOR_SHARE = 0.125
#: Tangent std-dev of a floor disc as a fraction of the floor grid's spacing (0.45: least error at 200 px; wider
#: discs overlap more, and front-to-back compositing then drags each tile line towards the camera).
FLOOR_DISC_SIZE = 0.45
FLOOR_OPACITY = 0.95
#: The objects' disc size and opacity (`motion_model`), below an object sample's (0.6, 0.95): the rasterizer adds
#: 0.3 px^2 to every projected covariance (`splatreel.constants.EPS2D`), so dense opaque discs spill about a pixel
#: past each silhouette, a dark halo on the white floor that dominates the error at 200 px. Thinner, fainter
#: discs that overlap less halve it (test PSNR of the default model: 24.9 dB against 22.0 dB; SSIM 0.880 against
#: 0.864), at the price of objects that look slightly see-through up close.
OBJECT_DISC_SIZE = 0.45
OBJECT_OPACITY = 0.5
#: A camera counts as seeing a floor point that projects within this fraction of the image size outside its
#: frame: discs just outside the frame still cover its edge pixels.
VIEW_MARGIN = 0.05
#: Spacing of the probe grid that measures the floor area to cover, world units.
PROBE_SPACING = 0.05


def default_model_gaussians(config: FloorConfig) -> int:
    """Gaussians of the scene's model for images of `config.size`: `GAUSSIANS_PER_PIXEL`, within bounds."""
    lo, hi = MODEL_GAUSSIANS_RANGE
    return int(np.clip(GAUSSIANS_PER_PIXEL * config.size ** 2, lo, hi))


def floor_votes(points: np.ndarray, cameras: list[Camera]) -> tuple[np.ndarray, np.ndarray]:
    """For ``(N, 3)`` floor points: how many of `cameras` see each (in front, within the frame plus
    `VIEW_MARGIN`), and how many of those see it nearer than `FAR_CLIP` (opaque in their images); ``(N,)`` ints."""
    seen = np.zeros(len(points), int)
    nearer = np.zeros(len(points), int)
    for cam in cameras:
        uv, depth = cam.project(points)
        mx, my = VIEW_MARGIN * cam.width, VIEW_MARGIN * cam.height
        inside = ((depth > 0) & (uv[:, 0] >= -mx) & (uv[:, 0] <= cam.width + mx)
                  & (uv[:, 1] >= -my) & (uv[:, 1] <= cam.height + my))
        seen += inside
        nearer += inside & (depth < FAR_CLIP)
    return seen, nearer


def floor_kept(points: np.ndarray, cameras: list[Camera]) -> np.ndarray:
    """``(N,)`` bool: floor points that most of the cameras seeing them see opaque (nearer than the far clip).

    The dataset's alpha shows each camera's floor up to its own clip line, so the views disagree near those
    lines (and the top camera sees no floor at all); a static floor cannot match them all, and the majority
    matches the most views.
    """
    seen, nearer = floor_votes(points, cameras)
    return (seen > 0) & (2 * nearer > seen)


def floor_grid(extent: float, spacing: float) -> np.ndarray:
    """``(M, 3)`` points ``(x, y, 0)`` of the square grid of `spacing` through the origin, ``|x|, |y| <= extent``."""
    n = math.floor(extent / spacing)
    ticks = spacing * np.arange(-n, n + 1)
    x, y = (a.ravel() for a in np.meshgrid(ticks, ticks, indexing="ij"))
    return np.stack([x, y, np.zeros_like(x)], -1)


def snap_spacing(spacing: float, tile: float) -> float:
    """The spacing nearest above `spacing` that puts grid points on every tile line (``tile / m``) or on every
    m-th (``tile * m``), so that the lines are sampled at their darkest."""
    if spacing <= tile:
        return tile / max(1, math.floor(tile / spacing))
    return tile * math.ceil(spacing / tile)


def floor_faces_at(ticks: np.ndarray, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(face ids ``(N,)``, barycentrics ``(N, 3)``) of the floor points ``(x, y)`` on the tensor grid of `ticks`
    that `floor_mesh` triangulates with `grid_faces` (quad (i, j) is faces ``2 q`` = (a, b, c) and ``2 q + 1``
    = (b, d, c), q = i (n - 1) + j, a..d its corners (i, j), (i + 1, j), (i, j + 1), (i + 1, j + 1))."""
    n = len(ticks)
    i = np.clip(np.searchsorted(ticks, x, side="right") - 1, 0, n - 2)
    j = np.clip(np.searchsorted(ticks, y, side="right") - 1, 0, n - 2)
    u = (x - ticks[i]) / (ticks[i + 1] - ticks[i])
    v = (y - ticks[j]) / (ticks[j + 1] - ticks[j])
    upper = u + v > 1.0
    face_ids = 2 * (i * (n - 1) + j) + upper
    bary = np.where(upper[:, None], np.stack([1.0 - v, u + v - 1.0, 1.0 - u], -1),
                    np.stack([1.0 - u - v, u, v], -1))
    return face_ids, bary


def floor_gaussians(scene: FloorScene, count: int, config: FloorConfig) -> Gaussians4D:
    """At most `count` (>= 1) static Gaussians laying the floor that `config`'s rig sees nearer than the far clip
    (`floor_kept`): flat discs on one square grid, std-dev `FLOOR_DISC_SIZE` x its spacing, coloured by the floor
    mesh's vertex colours there (tile lines included), lit by `shade`. They never move (velocity 0) and never fade
    (temporal std-dev 1000 over the clip: `static_gaussians4d`).

    The spacing is the finest that fits `count` over the kept area, snapped so that grid points lie on the tile
    lines (`snap_spacing`). It is the same everywhere: the far clip keeps the floor within about 4.1 of the origin
    and the floor nearest to a camera there is at depth ~2.5, so Gaussians growing with distance would save little.
    """
    cameras = [cam for _, _, cam in rig_cameras(config)]
    probe = floor_grid(scene.patch_half_size, PROBE_SPACING)
    kept = floor_kept(probe + [0.0, 0.0, scene.floor_z], cameras)
    extent = np.abs(probe[kept, :2]).max() + PROBE_SPACING
    spacing = snap_spacing(math.sqrt(kept.sum() * PROBE_SPACING ** 2 / max(count, 1)), scene.tile)
    while True:  # the probe's area is an estimate: coarsen until the grid fits the count
        points = floor_grid(extent, spacing) + [0.0, 0.0, scene.floor_z]
        points = points[floor_kept(points, cameras)]
        if len(points) <= count:
            break
        spacing = snap_spacing(spacing * 1.01, scene.tile)
    face_ids, bary = floor_faces_at(scene.floor_ticks(), points[:, 0], points[:, 1])
    _, normals, albedo = points_on_surface(scene._floor, face_ids, bary)
    std = FLOOR_DISC_SIZE * spacing
    n = len(points)
    f32 = dict(dtype=torch.float32)
    return static_gaussians4d(
        torch.tensor(points, **f32), torch.tensor([std, std, DISC_THICKNESS * std], **f32).repeat(n, 1),
        torch.tensor([1.0, 0.0, 0.0, 0.0], **f32).repeat(n, 1), torch.full((n,), FLOOR_OPACITY, **f32),
        torch.tensor(shade(albedo, normals), **f32))


def concat_models(models: list[Gaussians4D]) -> Gaussians4D:
    """One `Gaussians4D` holding the Gaussians of `models` in order (their SH degrees and conventions agree)."""
    return replace(models[0], **{k: torch.cat([getattr(m, k) for m in models]) for k in Gaussians4D.TENSORS})


# --- rig and timeline --------------------------------------------------------------------------------------------

def side_elevation(k: int) -> float:
    """Elevation (degrees) of side camera `k`: 11 levels from 10 to 45, visited with stride 4 so that cameras at
    neighbouring azimuths differ in elevation by 14 degrees or more (low and high views all around)."""
    lo, hi = SIDE_ELEVATIONS
    return lo + (hi - lo) * ((ELEVATION_STRIDE * k) % SIDE_CAMERAS) / (SIDE_CAMERAS - 1)


def rig_cameras(config: FloorConfig) -> list[tuple[float, float, Camera]]:
    """The 12 fixed cameras as (elevation, azimuth, camera), degrees: the side cameras, then the top one."""
    out = []
    for k in range(SIDE_CAMERAS):
        el, az = side_elevation(k), 360.0 * k / SIDE_CAMERAS
        out.append((el, az, orbit(el, az, SIDE_DISTANCE, fov_deg=config.fov, width=config.size,
                                  height=config.size, up="z")))
    # orbit() at 90 degrees would pick an arbitrary image up; say it: +y up on screen, +x to the right.
    top = look_at_c2w((0.0, 0.0, TOP_HEIGHT), (0.0, 0.0, 0.0), "y")
    out.append((90.0, 0.0, Camera.from_fov(top, config.size, config.size, fov_y_deg=config.fov)))
    return out


def train_times(frames: int) -> list[float]:
    """Every training frame has its own time ``i / (frames - 1)``."""
    return [i / (frames - 1) for i in range(frames)]


def train_views(config: FloorConfig) -> list[SampleView]:
    """Frame i at time ``i / (frames - 1)`` from camera ``i mod 12``, in that order."""
    rig = rig_cameras(config)
    out = []
    for i, t in enumerate(train_times(config.frames)):
        el, az, cam = rig[i % NUM_CAMERAS]
        out.append(SampleView("train", i, t, az, el, cam))
    return out


def test_plan(frames: int, count: int) -> list[tuple[float, int]]:
    """(time, camera) of each test image, ordered by time (stable).

    Image 0 is camera 6 at t = 0 (training frame 0 is camera 0). Image j > 0 is camera ``(j + 6) mod 12`` at the
    middle of a training interval: the one spread evenly over the clip like the object samples' test times, or the
    nearest one (the earlier on a tie) whose two training frames are seen by other cameras, so that no test image is
    its own camera's training image moved by half a frame.
    """
    steps = frames - 1
    plan = []
    for j in range(count):
        cam = (j + NUM_CAMERAS // 2) % NUM_CAMERAS
        if j == 0:
            plan.append((0.0, cam))
            continue
        target = math.floor((j - 1) * steps / max(count - 1, 1))
        free = [f for f in range(steps) if cam not in (f % NUM_CAMERAS, (f + 1) % NUM_CAMERAS)]
        f = min(free, key=lambda f: (abs(f - target), f))
        plan.append(((f + 0.5) / steps, cam))
    return sorted(plan, key=lambda p: p[0])


def test_views(config: FloorConfig) -> list[SampleView]:
    """The test images of `test_plan`: the rig's cameras at times between the training times."""
    rig = rig_cameras(config)
    return [SampleView("test", i, t, rig[c][1], rig[c][0], rig[c][2])
            for i, (t, c) in enumerate(test_plan(config.frames, config.test_views))]


def sample_json(scene: FloorScene, config: FloorConfig, renderer: MeshRenderer, train: list[SampleView],
                test: list[SampleView]) -> dict:
    """Provenance record written as ``sample.json`` (no timestamps: the dataset is byte-for-byte reproducible)."""
    rig = rig_cameras(config)
    cameras = [{"index": k, "kind": "top" if k == TOP_CAMERA else "side", "elevation": clean_number(el),
                "azimuth": clean_number(az), "position": [clean_number(x) for x in cam.position]}
               for k, (el, az, cam) in enumerate(rig)]
    return {
        "generator": "splatreel sample", "generator_version": GENERATOR_VERSION, "splatreel_version": __version__,
        "name": scene.name, "description": scene.description, "scene": scene.params(),
        "render": {**asdict(config), "supersample": renderer.supersample, "msaa": renderer.msaa,
                   "light_dir": [clean_number(x) for x in LIGHT_DIR], "ambient": AMBIENT, "diffuse": DIFFUSE,
                   "far_clip": FAR_CLIP, "background": "transparent (straight alpha)"},
        "alpha": ("coverage of surfaces nearer than the far clip (camera-space depth along the viewing axis, the GL "
                  "far plane), NOT an object mask: the top camera's floor lies beyond the clip (alpha 0) while "
                  "the side cameras see the same floor opaque up to the clip; the views disagree on purpose"),
        "world": "Blender: +z up; side cameras: orbit(up='z'), azimuth 0 on +x towards +y; all look at the origin",
        "cameras": cameras,
        "time_range": [0.0, 1.0],
        "frame_order": (f"train: r_i at time i/(frames-1), seen by camera i mod {NUM_CAMERAS} only; test: by time "
                        "(test image 0 at t=0, the others half-way between training times)"),
        "train_cameras": [i % NUM_CAMERAS for i in range(len(train))],
        "test_cameras": [c for _, c in test_plan(config.frames, config.test_views)],
        "splits": {"train": len(train), "test": len(test)},
    }


#: Scene name -> the scene (defaults); `SCENES` is name -> one-line description (listed by ``splatreel sample``).
SCENE_OBJECTS: dict[str, FloorScene] = {"floor": FloorScene()}
SCENES: dict[str, str] = {name: type(s).description for name, s in SCENE_OBJECTS.items()}
