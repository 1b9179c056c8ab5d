"""The ``texture`` sample: fine texture (bars, a checker band, text) as per-vertex colours on a dense banner that
ripples, bows and twists."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest
import torch

from splatreel.cameras import Camera, look_at_c2w
from splatreel.checkpoint import load_checkpoint
from splatreel.cli import main
from splatreel.samples import (BOUNDING_RADIUS, OBJECTS, SAMPLES, DatasetConfig, SampleConfigError, build_model,
                             get_sample)
from splatreel.samples.dataset import train_views
from splatreel.samples.geometry import signed_volume
from splatreel.samples.render import AMBIENT
from splatreel.samples.texture import BAR_WIDTHS, FRONT, OVERSAMPLE, Texture, band_layout, draw_face

TEXTURE = get_sample("texture")
VIEWS = train_views(DatasetConfig())
#: World units per pixel at the origin, default dataset camera (2.5 from the origin, fx = 280 px at 256 px).
PIXEL = DatasetConfig().radius / VIEWS[0].camera.fx
#: The banner at rest: no twist, turn, bow or ripple; its front (towards -y) lies in the plane y = -0.03.
FLAT = Texture(twist_deg=(0.0, 0.0), yaw_deg=(0.0, 0.0), bow=0.0, ripple=0.0)


def luminance(rgba: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(np.ascontiguousarray(rgba[..., :3]), cv2.COLOR_RGB2GRAY).astype(np.float64)


def strong_edges(rgba: np.ndarray) -> tuple[int, int]:
    """(pixels with a luminance Sobel magnitude above 100, of 255 levels; pixels counted), inside the fully
    covered area shrunk by 2 px so the silhouette's own edge does not count."""
    g = luminance(rgba)
    magnitude = np.hypot(cv2.Sobel(g, cv2.CV_64F, 1, 0), cv2.Sobel(g, cv2.CV_64F, 0, 1))
    inside = cv2.erode((rgba[..., 3] == 255).astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    return int((magnitude[inside] > 100.0).sum()), int(inside.sum())


def pairwise(points: np.ndarray) -> np.ndarray:
    return np.linalg.norm(points[:, None] - points[None], axis=-1)


def test_registered_with_the_other_objects():
    assert "texture" in SAMPLES and isinstance(OBJECTS["texture"], Texture)
    assert TEXTURE.params()["twist_deg"] == list(TEXTURE.twist_deg)  # JSON-able, as sample.json records it


def test_mesh_is_dense_enough_for_its_finest_detail():
    """Every edge between face vertices is shorter than a pixel of the default camera, and the finest bars are
    2 px wide: more than 2.4 vertex spacings even where the twist stretches the faces most, so vertex colours
    resolve them."""
    front, back = TEXTURE.face_vertices
    on_face = np.zeros(len(TEXTURE.mesh(0.0).vertices), bool)
    on_face[front.ravel()] = on_face[back.ravel()] = True
    for t in (0.0, 0.5, 1.0):
        m = TEXTURE.mesh(t)
        faces = m.faces[on_face[m.faces].all(1)]
        edges = np.concatenate([np.linalg.norm(m.vertices[faces[:, k]] - m.vertices[faces[:, (k + 1) % 3]], axis=1)
                                for k in range(3)])
        grid_edges = np.sort(edges)[: len(edges) * 2 // 3]  # the diagonals are the longest third
        assert edges.max() < 1.2 * PIXEL and grid_edges.max() < 0.85 * PIXEL, t
        assert min(BAR_WIDTHS) > 2.4 * grid_edges.max() and min(BAR_WIDTHS) > 1.99 * PIXEL


def test_deforms_inside_the_ball_with_the_texture_attached():
    start = TEXTURE.mesh(0.0)
    v0 = start.vertices
    front, back = TEXTURE.face_vertices
    for t in np.linspace(0.0, 1.0, 21):
        m = TEXTURE.mesh(t)
        assert np.array_equal(m.faces, start.faces)
        assert np.array_equal(m.colors, start.colors)  # the texture moves with the surface
        assert np.linalg.norm(m.vertices, axis=1).max() < BOUNDING_RADIUS - 0.1
        assert signed_volume(m.vertices, m.faces) > 0.04
        # the flag wave and bow move whole cross-sections: front and back stay one thickness apart
        gap = np.linalg.norm(m.vertices[front] - m.vertices[back[:, ::-1]], axis=-1)
        np.testing.assert_allclose(gap, 2.0 * TEXTURE.half_thickness, atol=1e-9)
    v1 = TEXTURE.mesh(1.0).vertices
    assert np.abs(v1 - v0).max() > 0.3
    # not rigid: distances between face points change (the twist, the bow)
    ids = front[::20, ::20].ravel()
    for t in (0.5, 1.0):
        v = TEXTURE.mesh(t).vertices
        assert np.abs(pairwise(v[ids]) - pairwise(v0[ids])).max() > 0.03, t
    np.testing.assert_array_equal(TEXTURE.mesh(-1.0).vertices, v0)  # times are clamped
    np.testing.assert_array_equal(TEXTURE.mesh(2.0).vertices, v1)


def test_deterministic():
    again = Texture()  # a fresh instance: texture and topology computed anew
    for a, b in zip(again.face_textures, TEXTURE.face_textures):
        np.testing.assert_array_equal(a, b)
    m, n = again.mesh(0.37), TEXTURE.mesh(0.37)
    np.testing.assert_array_equal(m.vertices, n.vertices)
    np.testing.assert_array_equal(m.colors, n.colors)


def test_a_training_view_has_far_more_fine_edges_than_the_wave(renderer):
    for index in (8 * 16 + 1, 15 * 16 + 10):  # the front, mid-animation; the back at the end
        view = VIEWS[index]
        texture = next(renderer.render(TEXTURE.mesh(view.time), [view.camera]))
        wave = next(renderer.render(get_sample("wave").mesh(view.time), [view.camera]))
        (edges, area), (wave_edges, wave_area) = strong_edges(texture), strong_edges(wave)
        assert area > 5000 and edges > 0.35 * area, "few strong edges on the banner"
        assert edges > 5 * wave_edges and edges / area > 3 * wave_edges / wave_area


def ideal_image(obj: Texture, cam: Camera, depth: float) -> np.ndarray:
    """``(H, W)`` luminance (0..255) of the ideal front drawing (`draw_face`, before any reduction to vertex
    colours) of the flat banner `obj`, seen by `cam` straight on from -y with the face `depth` away, each pixel
    averaged over 4 x 4 samples (close to the renderer's antialiasing)."""
    grid = obj.grid
    fine = draw_face(grid, FRONT, obj.margin).astype(np.float32)
    ys, xs = np.mgrid[0: cam.height, 0: cam.width]
    image = np.zeros((cam.height, cam.width, 3), np.float32)
    for oy in (np.arange(4) + 0.5) / 4:
        for ox in (np.arange(4) + 0.5) / 4:
            p = cam.unproject(np.stack([(xs + ox).ravel(), (ys + oy).ravel()], -1), np.full(xs.size, depth))
            # vertex units -> fine texels (vertex k owns fine texels k * OVERSAMPLE .. (k + 1) * OVERSAMPLE - 1)
            col = ((p[:, 0] + grid.half_width) / grid.da + 0.5) * OVERSAMPLE - 0.5
            row = ((grid.half_length - p[:, 2]) / grid.dz + 0.5) * OVERSAMPLE - 0.5
            col, row = (c.reshape(xs.shape).astype(np.float32) for c in (col, row))
            image += cv2.remap(fine, col, row, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE) / 16.0
    return luminance(image * 255.0)


def band_correlations(renderer, obj: Texture) -> list[tuple[str, float, float]]:
    """Per band of the front of the flat banner `obj` seen face-on by a default dataset camera: (band type,
    correlation of the rendered and the ideal luminance, ratio of their standard deviations)."""
    base = VIEWS[0].camera
    cam = Camera(look_at_c2w((0.0, -2.5, 0.0), (0.0, 0.0, 0.0), "z"), base.fx, base.fy, base.cx, base.cy, 256, 256)
    got = luminance(next(renderer.render(obj.mesh(0.0), [cam])))
    expected = ideal_image(obj, cam, 2.5 - obj.half_thickness)
    out = []
    for band, (top, bottom) in zip(FRONT, band_layout(FRONT, obj.half_length)):
        corners = np.array([[-obj.half_width + 0.01, -obj.half_thickness, top],
                            [obj.half_width - 0.01, -obj.half_thickness, bottom]])
        uv = cam.project(corners)[0]
        (x0, y0), (x1, y1) = np.ceil(uv[0]).astype(int), np.floor(uv[1]).astype(int)  # pixels inside the band
        a, b = got[y0:y1, x0:x1].ravel(), expected[y0:y1, x0:x1].ravel()
        assert a.size > 300
        out.append((type(band).__name__, float(np.corrcoef(a, b)[0, 1]), float(a.std() / b.std())))
    return out


def test_glyphs_and_bars_are_resolved_at_256_px(renderer):
    """The flat banner seen face-on by a default dataset camera: in every band of the front (three of text), the
    rendered image matches the ideal drawing of the face (glyphs as cv2.putText draws them, sharp bars and
    checks) to a correlation above 0.975 (0.98 to 0.995), keeping 85 % of the contrast that the ambient light
    gives it (the front faces away from the light here). A mesh with a 2 px vertex spacing blurs the text and the
    finest bars well below that (0.79 to 0.93)."""
    bands = band_correlations(renderer, FLAT)
    assert [kind for kind, _, _ in bands].count("TextBand") == 3
    for kind, corr, contrast in bands:
        assert corr > 0.975 and 0.85 * AMBIENT < contrast < 1.02 * AMBIENT, (kind, corr, contrast)
    coarse = band_correlations(renderer, replace(FLAT, spacing=2.0 * PIXEL))
    assert max(corr for _, corr, _ in coarse) < 0.95


def test_build_model_and_cli(tmp_path, capsys):
    model = build_model("texture", num_gaussians=3000, frames=4)
    assert len(model) == 3000
    rgb = model.slice(0.5).colors(torch.zeros(3)).numpy()
    assert rgb.std(0).min() > 0.1  # the model carries the texture's contrast
    ckpt = tmp_path / "t.safetensors"
    assert main(["sample", "texture", "--model", str(ckpt), "--gaussians", "2000", "--time-steps", "4"]) == 0
    assert len(load_checkpoint(ckpt).model) == 2000
    assert "texture" in capsys.readouterr().out


def test_bad_settings_are_refused():
    with pytest.raises(SampleConfigError, match="half_length"):
        Texture(half_length=0.3).face_textures  # the bands no longer fit on the face
    with pytest.raises(SampleConfigError, match="dimensions"):
        Texture(half_thickness=0.5)
