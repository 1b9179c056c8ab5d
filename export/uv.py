"""UVs and a baked colour texture for a mesh of one topology (``export mesh --deforming --uv``): the UVs stay put
while the vertices move, so a DCC tool can texture, paint or retopologise on top.

The atlas is xatlas's (jpcy/xatlas, the ``xatlas`` Python binding): it cuts the surface into charts and packs them
into [0, 1]², duplicating the vertices along the cuts (`Atlas.vertex_map` says which mesh vertex each UV vertex
comes from). The texture is the mesh's vertex colours interpolated over each triangle in UV space, then spread a
few texels past each chart's border so that filtering at the seams does not pull in the empty background.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: texels the colours are spread past each chart's border
BLEED_TEXELS = 4


@dataclass(frozen=True)
class Atlas:
    """vertex_map ``[U]``: the mesh vertex of each UV vertex; faces ``[F, 3]`` over the UV vertices; uvs ``[U, 2]``
    in [0, 1] (v up, as USD's ``st`` and OpenGL)."""

    vertex_map: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray


def atlas(vertices: np.ndarray, faces: np.ndarray) -> Atlas:
    """The UV atlas of a triangle mesh."""
    import xatlas

    vertex_map, uv_faces, uvs = xatlas.parametrize(vertices.astype(np.float32), faces.astype(np.uint32))
    return Atlas(vertex_map.astype(np.int64), uv_faces.astype(np.int64), uvs.astype(np.float64))


def bake_colors(layout: Atlas, colors: np.ndarray, size: int = 1024) -> np.ndarray:
    """``[size, size, 3]`` uint8 texture (row 0 at the top, v = 1) of per-vertex `colors` ``[V, 3]`` in [0, 1]
    (indexed like the mesh's vertices), interpolated over each triangle of the atlas."""
    import cv2

    texel = layout.uvs * size - 0.5  # texel centres at integer coordinates
    texel[:, 1] = size - 1 - texel[:, 1]  # v up -> rows down
    rgb = colors[layout.vertex_map]
    image = np.zeros((size, size, 3), np.float64)
    covered = np.zeros((size, size), bool)
    for tri in layout.faces:
        p = texel[tri]
        lo = np.maximum(np.floor(p.min(0)).astype(int), 0)
        hi = np.minimum(np.ceil(p.max(0)).astype(int), size - 1)
        if (hi < lo).any():
            continue
        xs, ys = np.meshgrid(np.arange(lo[0], hi[0] + 1), np.arange(lo[1], hi[1] + 1))
        q = np.stack([xs.ravel(), ys.ravel()], 1).astype(np.float64)
        m = np.array([p[1] - p[0], p[2] - p[0]]).T
        det = np.linalg.det(m)
        if abs(det) < 1e-12:
            continue
        b12 = np.linalg.solve(m, (q - p[0]).T).T
        bary = np.concatenate([1.0 - b12.sum(1, keepdims=True), b12], 1)
        inside = (bary >= -1e-6).all(1)
        rows, cols = q[inside, 1].astype(int), q[inside, 0].astype(int)
        image[rows, cols] = bary[inside] @ rgb[tri]
        covered[rows, cols] = True
    for _ in range(BLEED_TEXELS):  # each round: empty texels next to filled ones take their neighbours' mean
        weight = cv2.blur(covered.astype(np.float64), (3, 3))
        spread = cv2.blur(image * covered[..., None], (3, 3))
        grow = ~covered & (weight > 0)
        image[grow] = spread[grow] / weight[grow, None]
        covered = covered | grow
    return (np.clip(image, 0, 1) * 255 + 0.5).astype(np.uint8)


def with_atlas(meshes: list, layout: Atlas) -> list:
    """The `FrameMesh` list of one topology re-indexed to the atlas: vertices, normals and colours duplicated along
    its seams, its faces (the same at every frame)."""
    from dataclasses import replace

    m = layout.vertex_map
    return [replace(mesh, vertices=mesh.vertices[m], normals=mesh.normals[m], colors=mesh.colors[m],
                    faces=layout.faces) for mesh in meshes]


def texture_material(stage, mesh, uvs: np.ndarray, texture: str, path: str = "/World/Looks/Texture") -> None:
    """Give the `UsdGeom.Mesh` `mesh` the vertex primvar ``st`` (`uvs`) and a UsdPreviewSurface whose diffuse colour
    is the sRGB image file `texture` (relative to the stage) sampled at ``st`` (UsdPreviewSurface spec:
    UsdUVTexture, UsdPrimvarReader_float2)."""
    from pxr import Sdf, UsdGeom, UsdShade, Vt

    st = UsdGeom.PrimvarsAPI(mesh.GetPrim()).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                                                           UsdGeom.Tokens.vertex)
    st.Set(Vt.Vec2fArray.FromNumpy(np.ascontiguousarray(uvs, np.float32)))
    UsdGeom.Scope.Define(stage, path.rsplit("/", 1)[0])
    material = UsdShade.Material.Define(stage, path)
    surface = UsdShade.Shader.Define(stage, f"{path}/Surface")
    surface.CreateIdAttr("UsdPreviewSurface")
    reader = UsdShade.Shader.Define(stage, f"{path}/st")
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set("st")
    image = UsdShade.Shader.Define(stage, f"{path}/Image")
    image.CreateIdAttr("UsdUVTexture")
    image.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(Sdf.AssetPath(texture))
    image.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set("sRGB")
    image.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(reader.ConnectableAPI(), "result")
    rgb = image.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
    surface.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(rgb)
    material.CreateSurfaceOutput().ConnectToSource(surface.ConnectableAPI(), "surface")
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(material)
