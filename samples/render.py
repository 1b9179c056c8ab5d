"""Offscreen rendering of sample meshes with moderngl (EGL): lit, depth-tested, antialiased, straight-alpha RGBA.

Shading (``shaders/mesh.glsl``) is Lambert + ambient with a light fixed in world space, so a surface point has
the same colour from every camera; `shade` is the CPU twin of that formula.

Antialiasing: each image is drawn `supersample` times larger per axis into a float framebuffer with
`msaa` samples per pixel, resolved, then box-filtered down in numpy (``supersample**2 * msaa`` samples per pixel).
The clear colour is (0, 0, 0, 0) and every fragment writes alpha 1, so the filtered image is premultiplied colour
plus coverage; dividing by the coverage gives straight alpha (PNG convention).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable, Iterator

import numpy as np

from splatreel.cameras import Camera
from splatreel.gl import create_headless_context, load_program, with_context

from .geometry import Mesh

#: Unit vector towards the light, world space (+z up): from above, slightly to the side.
LIGHT_DIR = tuple(np.array([0.35, 0.25, 0.90]) / np.linalg.norm([0.35, 0.25, 0.90]))
AMBIENT = 0.35
DIFFUSE = 0.65
#: Clip planes of the GL projection (the objects sit within 0.9 of the origin, cameras well outside). A scene may
#: pass its own far plane to `MeshRenderer.draw`: everything beyond it is left transparent.
NEAR, FAR = 0.05, 100.0


def shade(albedo: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """CPU twin of the shader: ``(N, 3)`` albedo and unit normals -> ``(N, 3)`` lit colour in [0, 1]."""
    lambert = np.clip(normals @ np.asarray(LIGHT_DIR), 0.0, None)
    return np.clip(albedo * (AMBIENT + DIFFUSE * lambert)[:, None], 0.0, 1.0)


def view_projection(camera: Camera, far: float = FAR) -> tuple[np.ndarray, np.ndarray]:
    """(view, projection) 4x4 row-major matrices for GL: the OpenGL-axes world-to-camera and the projection
    (near plane `NEAR`, far plane `far`: camera-space depths, along the viewing axis)."""
    return np.linalg.inv(camera.to_opengl_c2w()), camera.opengl_projection(NEAR, far)


def resolve_straight_alpha(premultiplied: np.ndarray, factor: int) -> np.ndarray:
    """Box-filter a premultiplied float image ``(H*f, W*f, 4)`` (rows top first) by `factor` and return
    ``(H, W, 4)`` uint8 straight-alpha RGBA."""
    hf, wf, _ = premultiplied.shape
    h, w = hf // factor, wf // factor
    img = premultiplied.reshape(h, factor, w, factor, 4).mean(axis=(1, 3), dtype=np.float32)
    alpha = img[..., 3:]
    rgb = np.divide(img[..., :3], alpha, out=np.zeros_like(img[..., :3]), where=alpha > 0)
    out = np.concatenate([rgb, alpha], -1)
    return np.rint(np.clip(out, 0.0, 1.0) * 255.0).astype(np.uint8)


@dataclass
class _Target:
    msaa: object
    resolved: object


class MeshRenderer:
    """Draws `Mesh` objects for `Camera` views into RGBA arrays.

    Args:
        ctx: a moderngl context; a headless EGL one is created when None.
        supersample: per-axis render-size factor before the box filter (>= 1).
        msaa: multisample count of the framebuffer (1 disables MSAA; capped at what the driver offers).
    """

    def __init__(self, ctx=None, supersample: int = 2, msaa: int = 4) -> None:
        self.ctx = ctx if ctx is not None else create_headless_context()
        self.supersample = max(1, int(supersample))
        self._targets: dict[tuple[int, int], _Target] = {}
        self._vao = None
        self._buffers: list = []
        self._setup(msaa)

    @with_context
    def _setup(self, msaa: int) -> None:
        self.program = load_program(self.ctx, "mesh")
        self.msaa = max(1, min(int(msaa), int(self.ctx.max_samples)))
        self.program["u_light_dir"].value = tuple(float(x) for x in LIGHT_DIR)
        self.program["u_ambient"].value = AMBIENT
        self.program["u_diffuse"].value = DIFFUSE

    # --- resources -------------------------------------------------------------------------------------------
    def _target(self, width: int, height: int) -> _Target:
        size = (width * self.supersample, height * self.supersample)
        if size not in self._targets:
            ctx = self.ctx
            samples = self.msaa if self.msaa > 1 else 0
            msaa = ctx.framebuffer(color_attachments=[ctx.renderbuffer(size, 4, samples=samples, dtype="f4")],
                                   depth_attachment=ctx.depth_renderbuffer(size, samples=samples))
            resolved = ctx.framebuffer(color_attachments=[ctx.renderbuffer(size, 4, dtype="f4")])
            self._targets[size] = _Target(msaa, resolved)
        return self._targets[size]

    def _release_mesh(self) -> None:
        for obj in [self._vao, *self._buffers]:
            if obj is not None:
                obj.release()
        self._vao, self._buffers = None, []

    @with_context
    def upload(self, mesh: Mesh) -> None:
        """Make `mesh` the one that `draw` renders (positions, normals and colours as float32)."""
        self._release_mesh()
        attrs = np.concatenate([mesh.vertices, mesh.normals, mesh.colors], 1).astype("f4")
        vbo = self.ctx.buffer(np.ascontiguousarray(attrs).tobytes())
        ibo = self.ctx.buffer(np.ascontiguousarray(mesh.faces, dtype="i4").tobytes())
        self._vao = self.ctx.vertex_array(self.program, [(vbo, "3f 3f 3f", "in_position", "in_normal", "in_color")],
                                          index_buffer=ibo, index_element_size=4)
        self._buffers = [vbo, ibo]

    @with_context
    def draw(self, camera: Camera, far: float = FAR) -> np.ndarray:
        """``(H, W, 4)`` uint8 straight-alpha RGBA of the uploaded mesh seen by `camera` (rows top first).

        `far` is the far clip: surfaces whose camera-space depth (along the viewing axis) exceeds it are clipped
        by GL, so those pixels stay transparent like the background. The clipped edge is antialiased like any
        other edge."""
        if self._vao is None:
            raise RuntimeError("MeshRenderer.draw called before upload")
        if not NEAR < far:
            raise ValueError(f"far clip must exceed the near plane {NEAR}, got {far}")
        target = self._target(camera.width, camera.height)
        big = camera.resized(camera.width * self.supersample, camera.height * self.supersample)
        view, proj = view_projection(big, far)
        # moderngl takes column-major matrices: pass the transpose of the row-major arrays.
        self.program["u_view"].write(np.ascontiguousarray(view.T, dtype="f4").tobytes())
        self.program["u_proj"].write(np.ascontiguousarray(proj.T, dtype="f4").tobytes())
        ctx = self.ctx
        target.msaa.use()
        target.msaa.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        ctx.enable(ctx.DEPTH_TEST)
        ctx.disable(ctx.BLEND | ctx.CULL_FACE)
        self._vao.render()
        ctx.copy_framebuffer(target.resolved, target.msaa)
        raw = target.resolved.read(components=4, dtype="f4")
        w, h = big.width, big.height
        img = np.frombuffer(raw, dtype=np.float32).reshape(h, w, 4)[::-1]  # GL rows are bottom first
        return resolve_straight_alpha(img, self.supersample)

    def render(self, mesh: Mesh, cameras: Iterable[Camera]) -> Iterator[np.ndarray]:
        """Upload `mesh` once and yield one RGBA image per camera."""
        self.upload(mesh)
        for cam in cameras:
            yield self.draw(cam)

    @with_context
    def release(self) -> None:
        """Free GL objects (the context itself belongs to the caller when it was passed in)."""
        self._release_mesh()
        for t in self._targets.values():
            t.msaa.release()
            t.resolved.release()
        self._targets.clear()
        self.program.release()
