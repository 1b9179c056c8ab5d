"""Initial Gaussians for training: a random ball (Efficient4D) or coloured points on a user mesh (4DGen)."""

from __future__ import annotations

import math

import numpy as np
import torch

from splatreel import sh
from splatreel.datasets import Dataset
from splatreel.errors import SplatreelError


def look_at_centre(ds: Dataset) -> np.ndarray:
    """The point closest (least squares) to every training camera's optical axis: where the cameras look."""
    a = np.zeros((3, 3))
    b = np.zeros(3)
    for v in {v.view_id: v for v in ds.train}.values():
        d = v.camera.forward
        p = np.eye(3) - np.outer(d, d)
        a += p
        b += p @ v.camera.position
    try:
        c = np.linalg.solve(a, b)
    except np.linalg.LinAlgError:  # all axes parallel: fall back to the cameras' centroid
        c = np.mean([v.camera.position for v in ds.train], 0)
    return c


def default_init_radius(ds: Dataset, centre: np.ndarray) -> float:
    """80% of the smallest half-width of the views at the look-at centre: a ball every camera sees whole."""
    r = []
    for v in {v.view_id: v for v in ds.train}.values():
        dist = float(np.linalg.norm(v.camera.position - centre))
        half = min(math.tan(v.camera.fov_x / 2), math.tan(v.camera.fov_y / 2))
        r.append(dist * half)
    return 0.8 * min(r)


def random_ball(n: int, radius: float, centre: np.ndarray, generator: torch.Generator) -> torch.Tensor:
    """``[n, 3]`` points uniform in a ball (direction uniform on the sphere, radius r * cbrt(U))."""
    d = torch.randn(n, 3, generator=generator, dtype=torch.float64)
    d = d / torch.linalg.vector_norm(d, dim=-1, keepdim=True)
    r = radius * torch.rand(n, generator=generator, dtype=torch.float64) ** (1 / 3)
    return (d * r[:, None] + torch.from_numpy(centre)).float()


def mesh_points(path: str, n: int, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    """``[n, 3]`` points and ``[n, 3]`` RGB colours sampled on a mesh's surface (vertex/texture colours when it
    has them, else grey)."""
    import trimesh

    try:
        mesh = trimesh.load(path, force="mesh")
    except Exception as exc:  # trimesh raises many kinds for unreadable files
        raise SplatreelError(f"{path}: cannot read mesh ({str(exc).strip() or type(exc).__name__})") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise SplatreelError(f"{path}: no triangles in this mesh")
    try:
        pts, _, colors = trimesh.sample.sample_surface(mesh, n, sample_color=True, seed=seed)
        rgb = np.asarray(colors, dtype=np.float64)[:, :3] / 255.0
    except (AttributeError, ValueError, IndexError, TypeError):  # no colour information
        pts, _ = trimesh.sample.sample_surface(mesh, n, seed=seed)
        rgb = np.full((n, 3), 0.5)
    return torch.from_numpy(np.asarray(pts)).float(), torch.from_numpy(rgb).float()


def knn(points: torch.Tensor, k: int = 3) -> tuple[torch.Tensor, torch.Tensor]:
    """(indices ``[N, k]``, distances ``[N, k]``) of each point's k nearest other points (fewer when N <= k).

    An exact search in a k-d tree (scipy's ``cKDTree``, O(N log N), on every core), where a brute-force
    ``torch.cdist`` is O(N^2) time; distances come back in the dtype of `points`."""
    from scipy.spatial import cKDTree

    n = points.shape[0]
    kk = min(k + 1, n)  # the point itself comes first
    if kk < 2:
        return torch.zeros((n, 0), dtype=torch.long), torch.zeros((n, 0), dtype=points.dtype)
    xyz = points.detach().cpu().double().numpy()
    dist, idx = cKDTree(xyz).query(xyz, k=list(range(1, kk + 1)), workers=-1)
    return (torch.from_numpy(idx[:, 1:].astype(np.int64)).to(points.device),
            torch.from_numpy(dist[:, 1:]).to(points.device, points.dtype))


def nearest_neighbour_sq_dist(points: torch.Tensor, k: int = 3) -> torch.Tensor:
    """``[N]`` mean squared distance to the k nearest other points."""
    return (knn(points, k)[1] ** 2).mean(-1)


def initial_parameters(points: torch.Tensor, rgb: torch.Tensor, time_range: tuple[float, float],
                       sh_degree: int, sh_degree_t: int, generator: torch.Generator,
                       t_scale: float | None = None, t_means: torch.Tensor | None = None
                       ) -> dict[str, torch.Tensor]:
    """Raw Gaussians4D tensors at the official init (notes 4dgs-core §3.5): identity rotations, opacity 0.1,
    isotropic scale sqrt(mean sq. distance to 3 neighbours), mu_t ~ U[t0 - 0.1 D, t1 + 0.1 D], sigma_t = sqrt(D/5)
    (or `t_scale`; `t_means` when the points come with times), colour as the SH DC coefficient."""
    n = points.shape[0]
    t0, t1 = time_range
    dur = t1 - t0
    ident = torch.tensor([1.0, 0.0, 0.0, 0.0]).expand(n, 4).clone()
    m = sh.num_sh_coeffs(sh_degree, sh_degree_t)
    return {
        "means": points.clone(),
        "t_means": (torch.rand(n, generator=generator) * 1.2 - 0.1) * dur + t0 if t_means is None else t_means,
        "log_scales": torch.log(nearest_neighbour_sq_dist(points).clamp_min(1e-7).sqrt())[:, None].repeat(1, 3),
        "log_t_scales": torch.full((n,), math.log(t_scale or math.sqrt(dur / 5))),
        "quats_l": ident, "quats_r": ident.clone(),
        "opacity_logits": torch.full((n,), math.log(0.1 / 0.9)),
        "sh_dc": sh.rgb_to_sh(rgb)[:, None, :].float(),
        "sh_rest": torch.zeros(n, m - 1, 3),
    }


def start_static(raw: dict[str, torch.Tensor], share: float, time_range: tuple[float, float],
                 generator: torch.Generator) -> dict[str, torch.Tensor]:
    """A random `share` of the Gaussians `raw` made static at init: temporal mean at the middle of the clip and
    temporal std-dev the whole clip (visible at every time with at least 88% of their opacity, and no motion under
    identity rotations). With one camera per time, a short-lived Gaussian is seen by a handful of cameras and fits
    each of them on its own; a static one is shared by every camera, so what does not move (a floor, a backdrop)
    is fitted by all the views together. The optimizer shortens or fades the ones that land on moving parts."""
    n = raw["means"].shape[0]
    k = int(round(share * n))
    if k <= 0:
        return raw
    t_mean, log_t_scale = static_time(time_range)
    idx = torch.randperm(n, generator=generator)[:k]
    out = dict(raw)
    out["t_means"] = raw["t_means"].clone()
    out["t_means"][idx] = t_mean
    out["log_t_scales"] = raw["log_t_scales"].clone()
    out["log_t_scales"][idx] = log_t_scale
    return out


def static_time(time_range: tuple[float, float]) -> tuple[float, float]:
    """The temporal mean and log temporal std-dev of a static Gaussian: the clip's middle and its length (drawn at
    every time of the clip with at least 88 % of its opacity)."""
    t0, t1 = time_range
    return 0.5 * (t0 + t1), math.log(max(t1 - t0, 1e-6))


def foreground_masks(ds: Dataset) -> dict[int, np.ndarray]:
    """Each training view's foreground (alpha >= 0.5, dilated by 2 px) by its index in ``ds.train``: what `carve`
    tests against, computed once for all its rounds."""
    import cv2

    kernel = np.ones((5, 5), np.uint8)
    return {i: cv2.dilate((v.alpha >= 128).astype(np.uint8), kernel) > 0
            for i, v in enumerate(ds.train) if v.alpha is not None}


def carve(points: torch.Tensor, times: torch.Tensor, ds: Dataset, min_agreement: float = 0.9,
          masks: dict[int, np.ndarray] | None = None) -> torch.Tensor:
    """``[M]`` bool: which space-time candidates (points ``[M,3]`` at times ``[M]``) lie inside the object's visual
    hull: at the training frame nearest to each candidate's time, its projection must fall on the foreground
    (alpha >= 0.5, masks dilated by 2 px; `foreground_masks`, computed here when not given) in at least
    `min_agreement` of the views that see it."""
    masks = foreground_masks(ds) if masks is None else masks
    frame_times = np.asarray(ds.frame_times)
    nearest = np.abs(times.numpy()[:, None] - frame_times[None, :]).argmin(1)
    order = np.argsort(nearest, kind="stable")
    at_frame = np.split(order, np.searchsorted(nearest[order], np.arange(1, len(frame_times))))
    pts = points.double().numpy()
    votes = np.zeros(len(pts))
    seen = np.zeros(len(pts))
    for i, mask in masks.items():
        v = ds.train[i]
        sel = at_frame[int(np.abs(frame_times - v.time).argmin())]
        if sel.size == 0:
            continue
        uv, z = v.camera.project(pts[sel])
        w, h = v.size
        ij = np.floor(uv).astype(np.int64)
        inside = (z > 0) & (ij[:, 0] >= 0) & (ij[:, 0] < w) & (ij[:, 1] >= 0) & (ij[:, 1] < h)
        fg = np.zeros(sel.size, bool)
        fg[inside] = mask[ij[inside, 1], ij[inside, 0]]
        seen[sel[inside]] += 1
        votes[sel] += fg
    return torch.from_numpy((seen > 0) & (votes >= min_agreement * np.maximum(seen, 1)))


def carved_init(n: int, radius: float, centre: np.ndarray, ds: Dataset, generator: torch.Generator,
                max_rounds: int = 20) -> tuple[torch.Tensor, torch.Tensor] | None:
    """``n`` points and their times inside the visual hull (see `carve`), drawn from the init ball and the time
    range; None when the dataset has no masks or the hull is empty (the caller falls back to the plain ball)."""
    if all(v.alpha is None for v in ds.train):
        return None
    t0, t1 = ds.frame_times[0], ds.frame_times[-1]

    def draw() -> tuple[torch.Tensor, torch.Tensor]:
        cand = random_ball(4 * n, radius, centre, generator)
        return cand, t0 + (t1 - t0) * torch.rand(4 * n, generator=generator, dtype=torch.float64)
    return _keep_carved(n, draw, ds, generator, max_rounds)


def _keep_carved(n: int, draw, ds: Dataset, generator: torch.Generator, max_rounds: int
                 ) -> tuple[torch.Tensor, torch.Tensor] | None:
    """Draw candidate batches (``draw() -> (points, times)``) until `n` pass `carve` (all pass without masks);
    None when none does. A thin hull with fewer survivors reuses them (their scales come out small, which suits
    thin shapes)."""
    masks = foreground_masks(ds)
    kept_p, kept_t, total = [], [], 0
    for _ in range(max_rounds):
        cand, times = draw()
        ok = carve(cand, times, ds, masks=masks) if masks else torch.ones(len(cand), dtype=torch.bool)
        kept_p.append(cand[ok])
        kept_t.append(times[ok].float())
        total += int(ok.sum())
        if total >= n:
            break
    if total == 0:
        return None
    p, t = torch.cat(kept_p), torch.cat(kept_t)
    if total < n:
        idx = torch.randint(total, (n,), generator=generator)
        return p[idx], t[idx]
    return p[:n], t[:n]


def frustum_candidates(n: int, ds: Dataset, centre: np.ndarray, generator: torch.Generator,
                       depth_range: tuple[float, float] = (0.2, 2.5)) -> tuple[torch.Tensor, torch.Tensor]:
    """``n`` space-time candidates spread over what the training cameras see: a random training image, a random
    pixel of it that is opaque (any pixel without alpha), a depth uniform in `depth_range` times that camera's
    distance to `centre`, at the image's time. Unlike a ball around the look-at point this also reaches a floor or
    backdrop that runs out of the ball."""
    rng = np.random.default_rng(int(torch.randint(2**31 - 1, (1,), generator=generator)))
    per_view = np.bincount(rng.integers(len(ds.train), size=n), minlength=len(ds.train))
    points, times = [], []
    for v, k in zip(ds.train, per_view):
        if k == 0:
            continue
        w, h = v.size
        fg = np.flatnonzero(v.alpha >= 128) if v.alpha is not None else np.arange(w * h)
        if fg.size == 0:
            continue
        pix = fg[rng.integers(fg.size, size=k)]
        uv = np.stack([pix % w, pix // w], -1) + rng.random((k, 2))
        dist = float(np.linalg.norm(v.camera.position - centre))
        depth = dist * rng.uniform(*depth_range, size=k)
        points.append(v.camera.unproject(uv, depth))
        times.append(np.full(k, v.time))
    return torch.from_numpy(np.concatenate(points)).float(), torch.from_numpy(np.concatenate(times))


def frustum_init(n: int, ds: Dataset, centre: np.ndarray, generator: torch.Generator,
                 max_rounds: int = 20) -> tuple[torch.Tensor, torch.Tensor] | None:
    """``n`` points and times from `frustum_candidates`, kept where the masks agree (`carve`): the volume the
    cameras see, carved by the alpha masks. None when nothing survives."""
    return _keep_carved(n, lambda: frustum_candidates(2 * n, ds, centre, generator), ds, generator, max_rounds)


def point_cloud_init(path, n: int, ds: Dataset, generator: torch.Generator
                     ) -> tuple[torch.Tensor, torch.Tensor | None]:
    """(points, RGB or None) from a dataset's point cloud (`splatreel.train.points`): at most `n` of its points
    (a random subset when it has more), dropped when fewer than half lie in any training view (another frame)."""
    from .points import in_view_share, read_point_cloud

    xyz, rgb = read_point_cloud(path)
    share = in_view_share(xyz, {v.view_id: v.camera for v in ds.train}.values())
    if share < 0.5:
        raise SplatreelError(f"{path}: only {100 * share:.0f}% of its points lie in view of the training cameras "
                           "(another coordinate frame?); use --init ball or frustum")
    if len(xyz) > n:
        idx = torch.randperm(len(xyz), generator=generator)[:n].numpy()
        xyz, rgb = xyz[idx], None if rgb is None else rgb[idx]
    return torch.from_numpy(xyz).float(), None if rgb is None else torch.from_numpy(rgb).float()
