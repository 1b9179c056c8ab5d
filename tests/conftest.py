"""Fixtures shared by several test modules."""

import pytest


@pytest.fixture(scope="module")
def renderer():
    """One headless `MeshRenderer` (its GL context) per test module."""
    from splatreel.samples import MeshRenderer

    r = MeshRenderer()
    yield r
    r.release()


def round_trip_psnrs(original_path, returned_path, times=(0.25, 0.6)) -> list[float]:
    """PSNR (dB) between the renders of two checkpoints from one camera at `times`, on white: how much an export
    and its read-back changed what a model looks like."""
    import numpy as np

    from splatreel.cameras import orbit
    from splatreel.checkpoint import load_checkpoint
    from splatreel.viewer.renderer import RenderSettings, render_image

    a_model, b_model = load_checkpoint(original_path).model, load_checkpoint(returned_path).model
    cam = orbit(20, 30, 2.6, fov_deg=40, width=96, height=96)
    look = RenderSettings(background=(1.0, 1.0, 1.0))
    out = []
    for t in times:
        a = render_image(a_model, cam, t, look)[..., :3]
        b = render_image(b_model, cam, t, look)[..., :3]
        out.append(float(-10 * np.log10(np.mean((a - b) ** 2))))
    return out


def sample_dataset(tmp_path_factory, name: str, **config):
    """Write procedural sample `name` (its config class given `config`) to a fresh folder and return the folder."""
    from splatreel.samples import DatasetConfig, FloorConfig, write_dataset

    root = tmp_path_factory.mktemp("data") / name
    write_dataset(name, root, (FloorConfig if name == "floor" else DatasetConfig)(**config))
    return root


@pytest.fixture(scope="session")
def small_floor(tmp_path_factory):
    """An opaque floor to the horizon, one camera per time: 12 frames at 48 px (no camera films two consecutive
    frames)."""
    return sample_dataset(tmp_path_factory, "floor", frames=12, size=48, test_views=2)
