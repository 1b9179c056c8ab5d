"""Training views whose alpha contradicts the other views, and the pixels where the loss should not trust it.

Alpha is coverage: alpha 0 at a pixel says that nothing lies along its ray. Generated data often breaks that. A
renderer's alpha may mark what lies nearer than its far clip: the floor under a camera looking straight down is
then transparent while every side camera sees it opaque. A segmenter may matte a floor or a backdrop out of some
frames and not others. Trained as given, the views disagree about one surface, and the optimiser satisfies them all
with needles: edge-on, invisible to the camera that says "empty", covering the views that say "surface".

The test looks only at the static part of the scene, so that motion is never taken for disagreement. For every
camera seen at two or more times, *solid* pixels are opaque in every image of that camera (a static surface lies
along that ray) and *empty* pixels are transparent in every image of it (nothing lies along that ray, ever).

A point on the ray of an empty pixel (farther than a few pixels from anything the camera ever sees opaque) is
*contradicted* when at least `MIN_WITNESSES` other cameras see it and nearly all of them (`SOLID_SHARE`) see it on
solid pixels: in front of, on or behind a surface they always see. That happens to an object's visual hull only
in slivers along its silhouette, which the margin excludes, but to the whole floor under a camera that looks
straight down through it. An empty pixel with a contradicted point on its ray *conflicts*; a camera with conflicts
over at least `DETECT_SHARE` of its image disagrees with the others. The conflicting pixels, grown by
`REGION_GROWTH`, form the camera's conflict region: `AlphaConflicts.weight` gives a training image the loss weight
0 on its transparent pixels there and 1 elsewhere.

The test runs on masks reduced to at most `WORK_SIZE` pixels a side and a fixed sample of rays per camera, so it
costs a few seconds whatever the image size.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from splatreel.datasets import Dataset, DatasetImage

from .data import relative_name

#: Longer image side the masks are reduced to for the test.
WORK_SIZE = 128
#: Empty pixels tested per camera, and samples along each ray (out to 3x the farthest camera's distance).
RAYS_PER_CAMERA = 1500
SAMPLES_PER_RAY = 384
#: Alpha (of 255) at or above which a pixel is opaque, and below which it is transparent.
OPAQUE, TRANSPARENT = 230, 25
#: Empty pixels nearer than this (working pixels) to a pixel the camera ever sees opaque are not tested.
MARGIN = 3.0
#: A point is contradicted when at least this many other cameras see it, and this share of them see it solid.
MIN_WITNESSES, SOLID_SHARE = 3, 0.9
#: Share of a camera's image that must conflict for the views to be said to disagree.
DETECT_SHARE = 0.02
#: The conflict region grows this share of the image width around the conflicting points found.
REGION_GROWTH = 0.04


@dataclass
class _Camera:
    """One camera seen at several times, at the working resolution."""

    view: DatasetImage  # its first training view (pose, intrinsics, name)
    solid: np.ndarray  # [h, w] bool, opaque in every image
    empty_distance: np.ndarray  # [h, w] float32 pixels to the nearest ever-opaque pixel (0 on them)
    colour: np.ndarray  # [h, w, 3] uint8 median image

    @property
    def camera(self):
        h, w = self.solid.shape
        return self.view.camera.resized(w, h)


@dataclass
class CameraConflict:
    """How much of one camera's image is empty yet contradicts the other views."""

    view_id: int
    name: str  # its first training image
    tested: int  # empty pixels tested
    conflicting: int  # of which conflict
    empty_share: float  # share of the image that is empty (tested or not)

    @property
    def share(self) -> float:
        """Estimated share of the camera's image that conflicts."""
        return self.empty_share * self.conflicting / max(self.tested, 1)


@dataclass
class AlphaConflicts:
    """What `find_alpha_conflicts` found: whether it could test, per camera how much of its empty area conflicts,
    and per disagreeing camera (view id) the region ``[H, W]`` bool, at training resolution, of its conflicts."""

    checked: bool
    note: str = ""  # why it was not checked
    cameras: list[CameraConflict] = field(default_factory=list)
    regions: dict[int, np.ndarray] = field(default_factory=dict)
    surface_rgb: tuple[float, float, float] | None = None  # median colour other views see where it conflicts

    @property
    def disagreeing(self) -> list[CameraConflict]:
        return [c for c in self.cameras if c.share >= DETECT_SHARE]

    @property
    def detected(self) -> bool:
        return bool(self.disagreeing)

    @property
    def worst_share(self) -> float:
        """The largest share of a camera's image that conflicts (0 when nothing was tested)."""
        return max((c.share for c in self.cameras), default=0.0)

    def weight(self, view: DatasetImage) -> np.ndarray | None:
        """``[H, W]`` float32 loss weight of a training image (0 on its transparent pixels in the conflict region,
        1 elsewhere), or None when nothing in it conflicts."""
        region = self.regions.get(view.view_id)
        if region is None or view.alpha is None or region.shape != view.alpha.shape:
            return None
        w = ~(region & (view.alpha < 128))
        return None if w.all() else w.astype(np.float32)

    def conflict_share(self, views: list[DatasetImage]) -> float:
        """Share of the pixels of `views` whose loss weight is 0."""
        total = sum(v.alpha.size for v in views if v.alpha is not None) or 1
        zero = sum(int((w == 0).sum()) for v in views if (w := self.weight(v)) is not None)
        return zero / total


def _resize(img: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    import cv2

    return cv2.resize(img, size, interpolation=cv2.INTER_AREA) if img.shape[1::-1] != size else img


def _cameras(ds: Dataset) -> list[_Camera]:
    """The static masks of every camera that the training views show at two or more times."""
    import cv2

    groups: dict[int, list[DatasetImage]] = {}
    for v in ds.train:
        groups.setdefault(v.view_id, []).append(v)
    out = []
    for views in groups.values():
        if len({v.time for v in views}) < 2 or any(v.alpha is None for v in views):
            continue
        w, h = views[0].size
        scale = min(1.0, WORK_SIZE / max(w, h))
        size = (max(1, round(w * scale)), max(1, round(h * scale)))
        alphas = np.stack([_resize(v.alpha, size) for v in views])
        solid = cv2.erode((alphas >= OPAQUE).all(0).astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
        never = (alphas < TRANSPARENT).all(0).astype(np.uint8)
        dist = cv2.distanceTransform(never, cv2.DIST_L2, 3).astype(np.float32)
        colour = np.median(np.stack([_resize(v.image, size) for v in views]), 0).astype(np.uint8)
        out.append(_Camera(views[0], solid, dist, colour))
    return out


def _ray_directions(cam, pixels: np.ndarray) -> np.ndarray:
    """``[R, 3]`` world directions, per unit of camera depth, of the rays through pixel centres ``[R, 2]`` (integer
    x, y): the ray's point at depth d is ``cam.position + d * direction``."""
    uv = pixels + 0.5
    dirs = np.stack([(uv[:, 0] - cam.cx) / cam.fx, (uv[:, 1] - cam.cy) / cam.fy, np.ones(len(uv))], -1)
    return dirs @ cam.c2w[:3, :3].T


def _seen(cam: _Camera, origin: np.ndarray, directions: np.ndarray, depths: np.ndarray
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where camera `cam` sees the points of rays from `origin` ``[3]`` along `directions` ``[R, 3]`` at `depths`
    ``[S]``: (in view ``[R, S]`` bool, pixel x and y ``[R, S]`` int). A ray's points are linear in depth in any
    camera's frame too, so each camera-space coordinate is one outer product instead of a projection per point
    (the test projects every camera's rays into every other: this made it 1.8 times faster on the spinner)."""
    rot, shift = cam.camera.w2c[:3, :3], cam.camera.w2c[:3, 3]
    start, step = rot @ origin + shift, directions @ rot.T  # [3], [R, 3]
    x, y, z = (start[i] + step[:, i, None] * depths[None, :] for i in range(3))
    h, w = cam.solid.shape
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.floor(cam.camera.fx * x / z + cam.camera.cx)
        v = np.floor(cam.camera.fy * y / z + cam.camera.cy)
    inside = (z > 1e-6) & (u >= 0) & (u < w) & (v >= 0) & (v < h)
    return inside, np.where(inside, u, 0).astype(np.int64), np.where(inside, v, 0).astype(np.int64)


def find_alpha_conflicts(ds: Dataset, centre: np.ndarray | None = None, seed: int = 0) -> AlphaConflicts:
    """Test whether the training views' alpha agree (see module doc); `centre` is where the cameras look (default:
    the point nearest to every optical axis, as the init uses)."""
    import cv2

    from .initialize import look_at_centre

    if any(v.alpha is None for v in ds.train):
        return AlphaConflicts(False, "the images have no alpha")
    cams = _cameras(ds)
    if len(cams) < MIN_WITNESSES + 1:
        return AlphaConflicts(False, f"it needs {MIN_WITNESSES + 1} or more cameras that each see several times")
    centre = look_at_centre(ds) if centre is None else np.asarray(centre, np.float64)
    reach = max(float(np.linalg.norm(c.view.camera.position - centre)) for c in cams)
    depths = np.linspace(0.02 * reach, 3.0 * reach, SAMPLES_PER_RAY)
    rng = np.random.default_rng(seed)
    result = AlphaConflicts(True)
    colours = []
    for a, cam in enumerate(cams):
        ys, xs = np.nonzero(cam.empty_distance > MARGIN)
        marks_size = cam.solid.size
        if len(xs) == 0:
            continue
        pick = rng.choice(len(xs), min(RAYS_PER_CAMERA, len(xs)), replace=False)
        pixels = np.stack([xs[pick], ys[pick]], -1)
        directions = _ray_directions(cam.camera, pixels)
        shape = (len(pixels), len(depths))
        n_seen = np.zeros(shape, np.int32)
        n_solid = np.zeros(shape, np.int32)
        first_solid = np.full(shape + (3,), -1, np.int64)  # (camera, x, y) of one solid sighting, for colour
        for o, other in enumerate(cams):
            if o == a:
                continue
            inside, x, y = _seen(other, cam.camera.position, directions, depths)
            solid = inside & other.solid[y, x]
            n_seen += inside
            n_solid += solid
            new = solid & (first_solid[..., 0] < 0)
            first_solid[new] = np.column_stack([np.full(int(new.sum()), o), x[new], y[new]])
        contradicted = (n_seen >= MIN_WITNESSES) & (n_solid >= SOLID_SHARE * n_seen)
        bad = contradicted.any(1)
        name = relative_name(cam.view.name, ds.root)
        found = CameraConflict(cam.view.view_id, name, len(pixels), int(bad.sum()), len(xs) / marks_size)
        result.cameras.append(found)
        if found.share < DETECT_SHARE:
            continue
        marks = np.zeros(cam.solid.shape, np.uint8)
        marks[pixels[bad, 1], pixels[bad, 0]] = 1
        h, w = marks.shape
        k = 2 * max(1, round(REGION_GROWTH * w / 2)) + 1
        grown = cv2.dilate(marks, np.ones((k, k), np.uint8))
        result.regions[cam.view.view_id] = cv2.resize(grown, cam.view.size, interpolation=cv2.INTER_NEAREST) > 0
        hits = first_solid[contradicted]
        hits = hits[hits[:, 0] >= 0]
        colours.extend(cams[o].colour[y, x] for o, x, y in hits[:: max(1, len(hits) // 2000)])
    if not result.cameras:
        result.checked, result.note = False, "no camera has pixels that are transparent at every time"
    if colours:
        result.surface_rgb = tuple(float(x) for x in np.median(np.stack(colours), 0) / 255.0)
    return result


def describe(found: AlphaConflicts, strict: bool, views: list[DatasetImage]) -> str:
    """One line for the user: what was found and what training does about it."""
    if not found.checked:
        return f"alpha agreement not checked: {found.note}"
    if not found.detected:
        return (f"alpha agrees between views ({len(found.cameras)} cameras; at most "
                f"{100 * found.worst_share:.1f}% of a camera's image is transparent where the others see a surface)")
    bad = sorted(found.disagreeing, key=lambda c: -c.share)
    colour = "" if found.surface_rgb is None else \
        " of colour " + " ".join(f"{x:.2f}" for x in found.surface_rgb)
    head = (f"alpha disagrees between views: {len(bad)} of {len(found.cameras)} cameras (e.g. {bad[0].name}) are "
            f"transparent on {100 * bad[0].share:.0f}% of the image where the others see a surface{colour}")
    if strict:
        return head + "; --strict-alpha: training on the alpha as given"
    return head + (f"; those pixels get no loss ({100 * found.conflict_share(views):.1f}% of training pixels; "
                   "--strict-alpha keeps them)")
