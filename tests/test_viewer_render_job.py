"""`plan_render`: what ``splatreel render`` draws, decided without argparse or GL."""

from __future__ import annotations

import numpy as np
import pytest

from splatreel.errors import CameraError
from splatreel.viewer.options import OptionError
from splatreel.viewer.render_job import (DEFAULT_FPS, DEFAULT_PANORAMA_SIZE, DEFAULT_SIZE, RenderRequest,
                                         check_request, load_camera_path, plan_render)
from splatreel.viewer.render_settings import RenderSettings
from splatreel.viewer.synthetic import synthetic_model
from splatreel.viewer.trajectory import frame_model

from test_viewer_path import sample_path


@pytest.fixture(scope="module")
def model():
    return synthetic_model(500, seed=3, radius=0.4, scale=0.02)


def test_an_orbit_by_default(model):
    settings = RenderSettings(mode="depth")
    job = plan_render(RenderRequest(out="a.mp4", seconds=2.0), model, None, settings)
    assert job.size == DEFAULT_SIZE and job.fps == DEFAULT_FPS and job.frame_count == 60
    assert job.projection == "perspective" and job.equirect is None and job.settings is settings
    framing = frame_model(model)
    for cam in job.cameras:  # at one distance from the model's centre
        assert np.linalg.norm(cam.position - framing.center) == pytest.approx(framing.distance(40.0))
    t0, t1 = model.time_range  # loop mode: one pass every 2 s of video
    np.testing.assert_allclose(job.times[:3], t0 + (t1 - t0) * np.arange(3) / 30 / 2.0)


def test_a_spiral_held_at_a_time(model):
    job = plan_render(RenderRequest(out="s.mp4", trajectory="spiral", frame_count=8, size=(64, 48), fps=10,
                                    time=0.25, target=(0.0, 0.0, 0.0), distance=3.0, elevation=20, amplitude=15),
                      model, None, RenderSettings())
    assert job.frame_count == 8 and job.size == (64, 48) and job.cameras[0].width == 64
    np.testing.assert_allclose(job.times, 0.25)
    heights = [c.position[2] for c in job.cameras]
    assert min(heights) == pytest.approx(3.0 * np.sin(np.radians(5)))


def test_a_path_gives_frames_and_scene_times(model):
    path = sample_path()
    job = plan_render(RenderRequest(out="p.mp4", path_file="tour.json", fps=10), model, path, RenderSettings())
    assert job.frame_count == 41  # 4 s at 10 fps, the last key included
    assert job.times[0] == 0.0 and job.times[-1] == pytest.approx(1.0)  # the keys' scene_time


def test_equirect_defaults_to_a_2_to_1_panorama(model):
    job = plan_render(RenderRequest(out="pano.mp4", projection="equirect", frame_count=2), model, None,
                      RenderSettings())
    assert job.size == DEFAULT_PANORAMA_SIZE and job.equirect is not None


def test_requests_that_cannot_be_rendered(model):
    assert check_request(RenderRequest(out="still.png")).frame_count == 1
    for request, message in [
        (RenderRequest(out="a.mp4", fps=0), "--fps must be positive"),
        (RenderRequest(out="a.mp4", frame_count=0), "must be at least 1"),
        (RenderRequest(out="a.mp4", path_file="p.json", cameras="data"), "either --path or --cameras"),
        (RenderRequest(out="a.mp4", fov=180), "--fov must be in (0, 180)"),
        (RenderRequest(out="a.png", frame_count=3), "a.png holds one image, not 3 frames"),
    ]:
        with pytest.raises(OptionError) as exc:
            check_request(request)
        assert message in str(exc.value)
    with pytest.raises(OptionError, match="--trajectory path needs --path FILE or --cameras DATASET"):
        load_camera_path(RenderRequest(out="a.mp4", trajectory="path"), model.time_range)
    with pytest.raises(OptionError, match="does not apply to --time-mode loop"):
        plan_render(RenderRequest(out="a.mp4", time_mode="loop", time=0.5, frame_count=1), model, None,
                    RenderSettings())
    with pytest.raises(CameraError, match="needs a camera path"):
        plan_render(RenderRequest(out="a.mp4", time_mode="path", frame_count=1), model, None, RenderSettings())
