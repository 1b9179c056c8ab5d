"""Footprint caps and near plane (`splatreel.viewer.sorting.Footprint`): a splat drawn out to at most `max_std_dev`
std-devs, or to a share of the image height, is the uncapped splat inside that radius and nothing outside it, with
points and quads, in the sort's screen boxes, in picks and from the command line; a nearer near plane draws what the
trainer's culls."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import torch

from splatreel.cameras import look_at
from splatreel.checkpoint import save_checkpoint
from splatreel.cli import main
from splatreel.constants import EPS2D
from splatreel.viewer.renderer import GLError, RenderSettings, SplatRenderer, headless_context
from splatreel.viewer.sorting import Footprint
from test_viewer_sort import RED, gaussians_from_motion, swapping_pair

SIZE = 64
SIGMA = 0.15  # swapping_pair's isotropic std-dev (world units)
DISTANCE = 4.0


@pytest.fixture(scope="module")
def renderer():
    """The red Gaussian alone, at the origin at t = 0.5, seen head-on from DISTANCE: a round splat at the image
    centre with std-dev `sigma_px()`."""
    model = swapping_pair().select(torch.tensor([RED]))
    r = SplatRenderer(headless_context(), model)
    yield r
    r.release()


def camera():
    return look_at((-DISTANCE, 0.0, 0.0), (0.0, 0.0, 0.0), "z", fov_deg=30, width=SIZE, height=SIZE)


def sigma_px() -> float:
    """The splat's std-dev in pixels: f sigma / z, blurred by EPS2D (the Jacobian at the image centre)."""
    focal = camera().fy
    return math.sqrt((focal * SIGMA / DISTANCE) ** 2 + EPS2D)


def distances_px() -> np.ndarray:
    """[H, W] distance of each pixel centre from the image centre (where the splat is)."""
    cam = camera()
    y, x = np.mgrid[0:SIZE, 0:SIZE] + 0.5
    return np.hypot(x - cam.cx, y - cam.cy)


def alpha(r: SplatRenderer, **caps) -> np.ndarray:
    r.render(camera(), 0.5, RenderSettings(transparent=True, **caps))
    return r.read_display()[..., 3]


@pytest.mark.parametrize("caps, radius_px", [
    ({"max_std_dev": 2.0}, 2.0 * sigma_px()),
    ({"max_screen_radius": 0.1}, 0.1 * SIZE),
    ({"max_std_dev": 2.5, "max_screen_radius": 0.1}, 0.1 * SIZE),  # the tighter one wins
])
@pytest.mark.parametrize("primitive", ["points", "quads"])
def test_a_capped_splat_is_the_splat_inside_the_cap_and_nothing_outside(renderer, caps, radius_px, primitive):
    d = distances_px()
    full = alpha(renderer, primitive=primitive)
    capped = alpha(renderer, primitive=primitive, **caps)
    inside, outside = d < radius_px - 0.5, d > radius_px + 0.5
    assert inside.sum() > 20
    np.testing.assert_allclose(capped[inside], full[inside], atol=1e-6)
    assert capped[outside].max() == 0.0
    # the uncapped splat does reach past the cap (to ~3.3 std-devs), so the cap took something away
    assert (full[outside] > 0).sum() > 50 and (d[full > 0].max()) > 3.0 * sigma_px()


def elongated_gaussian():
    """One static Gaussian at the origin, 9x longer along world y than across (std-devs 0.05, 0.45, 0.05)."""
    return gaussians_from_motion([[0.0, 0.0, 0.0]], torch.diag(torch.tensor([0.05, 0.45, 0.05]) ** 2), [0.0] * 3,
                                 100.0, 3.0, [1.0, 1.0, 1.0])


@pytest.mark.parametrize("caps", [{"max_screen_radius": 0.3}, {"max_std_dev": 1.7}])
@pytest.mark.parametrize("primitive", ["points", "quads"])
def test_a_rotated_elongated_splat_is_cut_where_the_trainers_projection_says(caps, primitive):
    """An elongated splat seen with the camera rolled by 30 degrees: the cut follows its 2D covariance from the
    trainer's projection, the screen cap along the major axis (sqrt(lambda_1) px per std-dev) and not along an
    image axis; the sort's box holds every drawn pixel."""
    from splatreel.rasterize import project_gaussians

    model = elongated_gaussian()
    roll = math.radians(30)
    cam = look_at((-DISTANCE, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, math.sin(roll), math.cos(roll)), fov_deg=30,
                  width=SIZE, height=SIZE)
    g = model.slice(0.0)
    p = project_gaussians(g.means.double(), g.covariances.double(), cam)
    xx, xy, yy = (float(v) for v in p.cov2d[0])
    conic = np.linalg.inv([[xx, xy], [xy, yy]])
    lambda_2, lambda_1 = np.linalg.eigvalsh([[xx, xy], [xy, yy]])
    assert lambda_1 > 4 * lambda_2 and abs(xy) > 0.2 * math.sqrt(xx * yy)  # elongated, not along an image axis
    rr = min(2.0 * math.log(float(g.opacities[0]) * 255.0),  # the cut-off, then the caps
             caps.get("max_std_dev", math.inf) ** 2, (caps.get("max_screen_radius", math.inf) * SIZE) ** 2 / lambda_1)
    y, x = np.mgrid[0:SIZE, 0:SIZE] + 0.5
    d = np.stack([x - float(p.means2d[0, 0]), y - float(p.means2d[0, 1])], -1)
    r2 = np.einsum("...i,ij,...j->...", d, conic, d)
    r = SplatRenderer(headless_context(), model)
    settings = RenderSettings(transparent=True, primitive=primitive)
    r.render(cam, 0.0, settings)
    full = r.read_display()[..., 3]
    r.render(cam, 0.0, replace(settings, **caps))
    capped = r.read_display()[..., 3]
    box = r.sort(cam, 0.0, replace(settings, **caps).footprint).boxes[0]
    r.release()
    inside, outside = r2 < 0.97 * rr, r2 > 1.03 * rr
    assert inside.sum() > 30 and (full[outside] > 0).sum() > 30
    np.testing.assert_allclose(capped[inside], full[inside], atol=1e-5)  # (a quad's offsets are interpolated)
    assert capped[outside].max() == 0.0
    drawn_x, drawn_y = x[capped > 0], y[capped > 0]
    assert np.all(np.abs(drawn_x - box[0]) <= box[2]) and np.all(np.abs(drawn_y - box[1]) <= box[3])
    assert box[2] == pytest.approx(math.sqrt(rr * xx) + 1.0, rel=1e-3)
    assert box[3] == pytest.approx(math.sqrt(rr * yy) + 1.0, rel=1e-3)


def test_no_cap_changes_nothing_and_a_cap_beyond_the_cut_off_is_no_cap(renderer):
    full = alpha(renderer)
    assert RenderSettings().footprint == Footprint()
    np.testing.assert_array_equal(alpha(renderer, max_std_dev=3.5, max_screen_radius=10.0), full)


def test_the_sort_boxes_follow_the_cap(renderer):
    """The screen boxes that choose points or quads and skip hidden Gaussians shrink with the cap: half-width
    = radius * sigma_px + 1 px of slack."""
    for footprint, reach in ((Footprint(max_std_dev=2.0), 2.0 * sigma_px()),
                             (Footprint(max_screen_radius=0.1), 0.1 * SIZE)):
        box = renderer.sort(camera(), 0.5, footprint).boxes[0]
        assert box[2] == pytest.approx(reach + 1.0, rel=1e-3) and box[3] == pytest.approx(reach + 1.0, rel=1e-3)
    full = renderer.sort(camera(), 0.5).boxes[0]
    assert full[2] > 3.2 * sigma_px()


def test_pick_sees_the_capped_splat(renderer):
    cam = camera()
    x = int(cam.cx + 2.6 * sigma_px())  # a pixel between 2.5 and 2.85 std-devs right of the centre
    capped = RenderSettings(max_std_dev=2.0)
    assert renderer.pick(cam, 0.5, x, SIZE // 2).hits
    assert not renderer.pick(cam, 0.5, x, SIZE // 2, capped).hits
    near = renderer.pick(cam, 0.5, SIZE // 2 + 3, SIZE // 2, capped)
    assert near.alpha == pytest.approx(float(alpha(renderer, max_std_dev=2.0)[SIZE // 2, SIZE // 2 + 3]), abs=1e-5)


def test_a_nearer_near_plane_draws_a_gaussian_the_default_one_culls(renderer):
    """0.15 in front of the camera: culled at the trainer's 0.2 (nothing drawn, sorted or picked), drawn, sorted
    and picked with the near plane at 0.1."""
    cam = look_at((-0.15, 0.0, 0.0), (0.0, 0.0, 0.0), "z", fov_deg=30, width=SIZE, height=SIZE)
    centre = (SIZE // 2, SIZE // 2)
    for near, drawn in ((None, False), (0.1, True)):
        settings = RenderSettings(transparent=True, **({} if near is None else {"near_plane": near}))
        renderer.render(cam, 0.5, settings)
        a = renderer.read_display()[..., 3]
        assert (a.max() > 0.5) == drawn and (a.max() > 0) == drawn
        assert renderer.sort(cam, 0.5, settings.footprint).visible == int(drawn)
        stack = renderer.pick(cam, 0.5, *centre, settings)
        assert bool(stack.hits) == drawn and stack.alpha == pytest.approx(float(a[centre[1], centre[0]]), abs=1e-5)


@pytest.mark.parametrize("caps", [{"max_std_dev": 0.0}, {"max_std_dev": -1.0}, {"max_screen_radius": math.nan},
                                  {"near_plane": 0.0}])
def test_caps_must_be_positive(caps):
    with pytest.raises(GLError, match="must be a positive number"):
        RenderSettings(**caps)


def test_render_command_caps_splats_and_rejects_bad_values(tmp_path, capsys):
    ckpt = tmp_path / "one.safetensors"
    save_checkpoint(ckpt, swapping_pair().select(torch.tensor([RED])))
    view = ["--trajectory", "orbit", "--size", "64x64", "--time", "0.5", "--background", "transparent", "--quiet"]
    covered = {}
    for name, extra in (("full", []), ("capped", ["--max-std-dev", "1.5"])):
        out = tmp_path / f"{name}.exr"
        assert main(["render", str(ckpt), "--out", str(out), *view, *extra]) == 0
        import OpenImageIO as oiio

        covered[name] = int((oiio.ImageBuf(str(out)).get_pixels(oiio.FLOAT)[..., 3] > 0).sum())
    # the area goes with the reach squared: (1.5 / ~3.3)^2 ~ 0.2 of the pixels
    assert 0.1 * covered["full"] < covered["capped"] < 0.35 * covered["full"]
    capsys.readouterr()
    for bad in (["--max-std-dev", "0"], ["--max-screen-radius", "wide"], ["--near-plane", "-1"]):
        with pytest.raises(SystemExit):
            main(["render", str(ckpt), "--out", str(tmp_path / "x.png"), *view, *bad])
        err = capsys.readouterr().err
        assert "expected a positive number" in err and "Traceback" not in err
