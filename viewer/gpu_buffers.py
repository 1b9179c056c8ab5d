"""The splat renderer's GPU objects, each group made and released together: a model's splats (`SplatBuffers`) and
the framebuffers of one image size (`RenderTargets`). `SplatRenderer` owns one of each; the shaders they feed are
``shaders/splat_preprocess.glsl``, ``splat_draw.glsl`` and ``splat_screen.glsl``, whose uniforms `set_uniforms` sets.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from splatreel.errors import GLError

from .draw_plan import OCCLUSION_TILE

#: Bytes of one pre-processed Gaussian (4 vec4: geometry, axes, colour, tile rectangle).
SPLAT_BYTES = 64
#: The vec4 fields of a pre-processed Gaussian, in buffer order (splat_draw.glsl attribute names).
SPLAT_FIELDS = ("i_geom", "i_axes", "i_color", "i_rect")
#: Width of the SH coefficient texture (narrower only when the GPU's texture limit needs more rows).
SH_TEX_WIDTH = 4096
#: GL_NEAREST: textures read by texelFetch, or 1:1
_NEAREST = 0x2600
#: The pre-pass attributes (vec4 each), in `SplatArrays.attributes` order; a skinned model's two more after them.
ATTRIBUTES = ("a_mean_t", "a_motion", "a_accel", "a_cov_a", "a_cov_b")
SKIN_ATTRIBUTES = ("a_skin_nodes", "a_skin_weights")


def sh_texture_size(count: int, texels: int, num_coeffs: int, max_size: int) -> tuple[int, int]:
    """(width, rows) of the texture holding `texels` RGBA texels of SH coefficients for each of `count` Gaussians;
    raises GLError (one line) when they exceed this GPU's `max_size` texture side."""
    width = SH_TEX_WIDTH
    rows = max(1, -(-count * texels // width))
    if rows > max_size:
        width = max_size
        rows = max(1, -(-count * texels // width))
        if rows > max_size:
            raise GLError(f"{count:,} Gaussians with {num_coeffs} colour coefficients exceed this GPU's "
                          f"texture limits ({max_size}x{max_size}); lower the SH degree")
    return width, rows


@dataclass
class SplatBuffers:
    """A model's splats on the GPU: the per-Gaussian attributes (`ATTRIBUTES`: 20 floats; a skinned model's 8 more,
    `SKIN_ATTRIBUTES`) and SH coefficients (an RGBA float texture) the pre-pass reads, a skinned model's node
    texture (`splatreel.viewer.skinning`, rewritten per displayed time), the index buffer it reads them through (the
    draw order), its output (one `SPLAT_BYTES` record per Gaussian, `SPLAT_FIELDS`) and the vertex arrays that draw
    those records with each splat program."""

    count: int
    attrs: object
    sh: object
    indices: object
    splats: object
    #: the pre-pass over `attrs` through `indices`, and its program (compiled for the model's SH degrees)
    pre_vao: object
    pre_prog: object
    #: kind ("quads", "points", "overlay") -> vertex array of `splats` for that kind's program
    splat_vaos: dict
    #: a skinned model's node texture (None for other models) and the time its poses are for
    nodes: object = None
    nodes_time: float | None = None

    @classmethod
    def create(cls, ctx, attrs: np.ndarray, sh: np.ndarray, sh_size: tuple[int, int], pre_prog,
               splat_progs: dict, node_size: tuple[int, int] | None = None) -> "SplatBuffers":
        """Upload ``[N, 20]`` float32 `attrs` (``[N, 28]`` with a skin) and the ``[W * H, 4]`` float32 `sh` texels of
        a `sh_size` (W, H) texture, make a skinned model's node texture of `node_size` (texels per node, nodes), and
        make the vertex arrays of the pre-pass program and of each splat program."""
        n = len(attrs)
        cap = max(n, 1)
        names = ATTRIBUTES + (SKIN_ATTRIBUTES if node_size is not None else ())
        attr_buf = ctx.buffer(attrs.tobytes() if n else b"\0" * 16 * len(names))
        sh_tex = ctx.texture(sh_size, 4, sh.tobytes(), dtype="f4")
        sh_tex.filter = (_NEAREST, _NEAREST)
        nodes = None
        if node_size is not None:
            max_size = int(ctx.info.get("GL_MAX_TEXTURE_SIZE", 16384))
            if node_size[1] > max_size:
                raise GLError(f"{node_size[1]:,} control nodes exceed this GPU's texture limit ({max_size})")
            nodes = ctx.texture(node_size, 4, dtype="f4")
            nodes.filter = (_NEAREST, _NEAREST)
        indices = ctx.buffer(reserve=4 * cap)
        splats = ctx.buffer(reserve=SPLAT_BYTES * cap)
        splat_vaos = {}
        for kind, prog in splat_progs.items():
            used = [name for name in SPLAT_FIELDS if name in prog]
            fmt = " ".join("4f" if name in used else "16x" for name in SPLAT_FIELDS)
            fmt += "" if kind == "points" else "/i"  # a quad is one instance of a 4-vertex strip
            splat_vaos[kind] = ctx.vertex_array(prog, [(splats, fmt, *used)])
        fmt = " ".join("4f" if name in pre_prog else "16x" for name in names)  # (a skinned program reads no a_accel)
        pre_vao = ctx.vertex_array(pre_prog, [(attr_buf, fmt, *(name for name in names if name in pre_prog))],
                                   index_buffer=indices, index_element_size=4)
        return cls(n, attr_buf, sh_tex, indices, splats, pre_vao, pre_prog, splat_vaos, nodes)

    def write(self, attrs: np.ndarray, sh: np.ndarray) -> None:
        """Rewrite the attributes and SH texels in place (as many Gaussians, same layout: a keyframed re-slice)."""
        self.attrs.write(attrs.tobytes())
        self.sh.write(sh.tobytes())

    def pose_nodes(self, keys, t: float) -> None:
        """Write a skinned model's node poses at `t` (`skinning.NodeKeys.texels` of `keys`) unless already there."""
        if self.nodes_time != t:
            self.nodes.write(keys.texels(t).tobytes())
            self.nodes_time = t

    def release(self) -> None:
        extra = () if self.nodes is None else (self.nodes,)
        for obj in (*self.splat_vaos.values(), self.pre_vao, self.attrs, self.sh, self.indices, self.splats, *extra):
            obj.release()


@dataclass
class RenderTargets:
    """The framebuffers of one image size: the float accumulation (premultiplied colour, alpha = 1 - T) with the
    depth buffer that masks saturated pixels, the depth-only mask pass, the resolved display image, and the
    saturated-tile flags (one texel per `OCCLUSION_TILE` square) read back between draw stages."""

    size: tuple[int, int]
    accum_tex: object
    depth_rb: object
    accum_fbo: object
    mask_fbo: object
    display_tex: object
    display_fbo: object
    tiles_tex: object
    tiles_fbo: object

    @classmethod
    def create(cls, ctx, size: tuple[int, int]) -> "RenderTargets":
        """The targets of a `size` (width, height) image; raises GLError (one line) past this GPU's limit."""
        max_size = int(ctx.info.get("GL_MAX_RENDERBUFFER_SIZE", 16384))
        if size[0] > max_size or size[1] > max_size:
            raise GLError(f"image size {size[0]}x{size[1]} exceeds this GPU's limit of {max_size} pixels")
        accum = ctx.texture(size, 4, dtype="f4")
        accum.filter = (_NEAREST, _NEAREST)
        accum.repeat_x = accum.repeat_y = False  # a stretched resolve must not blend in the opposite edge
        depth = ctx.depth_renderbuffer(size)
        display = ctx.texture(size, 4, dtype="f4")
        tiles = ctx.texture((-(-size[0] // OCCLUSION_TILE), -(-size[1] // OCCLUSION_TILE)), 1, dtype="f1")
        return cls(size, accum, depth, ctx.framebuffer([accum], depth), ctx.framebuffer([], depth), display,
                   ctx.framebuffer([display]), tiles, ctx.framebuffer([tiles]))

    def release(self) -> None:
        for obj in (self.accum_fbo, self.mask_fbo, self.display_fbo, self.tiles_fbo, self.accum_tex, self.depth_rb,
                    self.display_tex, self.tiles_tex):
            obj.release()


def set_uniforms(prog, **values) -> None:
    """Set uniforms by name, skipping those the GLSL compiler optimised away (e.g. u_campos at SH degree 0).

    2-D numpy arrays are written as raw float32 bytes (matrices, already column-major); other values are cast to
    the uniform's own type (int or float, scalar or vector).
    """
    for name, value in values.items():
        if name not in prog:
            continue
        uniform = prog[name]
        if isinstance(value, np.ndarray) and value.ndim == 2:
            uniform.write(value.astype(np.float32).tobytes())
            continue
        cast = int if uniform.fmt.endswith("i") else float
        if np.ndim(value) == 0:
            uniform.value = cast(value)
        else:
            uniform.value = tuple(cast(v) for v in value)
