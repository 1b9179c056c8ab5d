"""Selecting and deleting Gaussians (`splatreel.viewer.selection`) and the app's Edit state on a headless renderer:
what a rectangle selects at time t, the selection markers, delete / undo / restore, and what "Save edited" writes."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from splatreel.cameras import look_at, orbit
from splatreel.checkpoint import load_checkpoint, save_checkpoint
from splatreel.constants import ALPHA_THRESHOLD, NEAR_PLANE
from splatreel.rasterize import project_gaussians
from splatreel.viewer.renderer import RenderSettings, SplatRenderer, headless_context, render_image
from splatreel.viewer.selection import MAX_MARKERS, UNDO_LEVELS, Edits, centres_at, in_rect, marker_segments
from splatreel.viewer.sorting import depth_order
from splatreel.viewer.splats import to_arrays
from splatreel.viewer.synthetic import synthetic_model
from test_viewer_sort import BLUE, RED, swapping_pair


def test_a_rectangle_selects_what_shows_in_it_at_time_t():
    """Two Gaussians that swap sides over time: the left half of the image holds red at t = 0 and blue at t = 1."""
    model = swapping_pair()
    cam = look_at((0.0, -6.0, 0.0), (0.0, 0.0, 0.0), "z", fov_deg=40, width=64, height=48)  # x runs left to right
    splats = to_arrays(model)
    left, right = (0, 0, 32, 48), (64, 48, 32, 0)  # any two opposite corners
    assert in_rect(depth_order(splats, cam, 0.0), left).tolist() == [RED]
    assert in_rect(depth_order(splats, cam, 0.0), right).tolist() == [BLUE]
    assert in_rect(depth_order(splats, cam, 1.0), left).tolist() == [BLUE]
    assert in_rect(depth_order(splats, cam, 0.5), (0, 0, 64, 10)).tolist() == []  # both cross the middle row


def test_a_rectangle_selects_the_centres_the_trainer_projects_into_it():
    """Against the model's own slice and the trainer's projection: a rectangle selects exactly the Gaussians drawn
    at t (not faded out, opacity >= 1/255, in front) whose projected centre lies in it, through every depth."""
    model = synthetic_model(4000, seed=5, radius=0.5, scale=0.02, speed=0.4, lifetime=0.15)
    cam = orbit(20, 40, 2.0, fov_deg=50, width=120, height=90)
    rect = (20.5, 10.0, 90.0, 70.5)
    for t in (0.2, 0.7):
        chosen = in_rect(depth_order(to_arrays(model), cam, t), rect)
        g = model.slice(t)
        p = project_gaussians(g.means.double(), g.covariances.double(), cam)
        u, v = p.means2d.numpy().T
        opacity, z = g.opacities.double().numpy(), p.depths.numpy()
        drawn = g.visible.numpy() & (opacity >= ALPHA_THRESHOLD) & (z > NEAR_PLANE)
        inside = (u >= rect[0]) & (u < rect[2]) & (v >= rect[1]) & (v < rect[3])
        expected = np.flatnonzero(drawn & inside)
        assert len(expected) > 50 and (inside & ~drawn).sum() > 50  # short-lived: many centres there are faded out
        assert chosen.tolist() == expected.tolist()


def test_markers_are_crosses_of_the_asked_size_in_front_of_the_camera():
    cam = look_at((0.0, -4.0, 0.0), (0.0, 0.0, 0.0), "z", fov_deg=40, width=64, height=64)
    points = np.array([[0.0, 0.0, 0.0], [0.3, 1.0, 0.2], [0.0, -5.0, 0.0]])  # the last is behind the camera
    segs = marker_segments(points, cam, pixels=6.0)
    assert segs.shape == (6, 2, 3)
    w2c = np.asarray(cam.w2c)
    for seg, centre in zip(segs.reshape(2, 3, 2, 3), points[:2]):
        np.testing.assert_allclose(seg.mean(1), np.broadcast_to(centre, (3, 3)), atol=1e-12)  # centred on it
        ends = seg[0] @ w2c[:3, :3].T + w2c[:3, 3]  # the world x arm, across the view
        uv = ends[:, :2] / ends[:, 2:] * cam.fx
        assert abs(np.linalg.norm(uv[1] - uv[0]) - 6.0) < 1e-9
    many = marker_segments(np.zeros((MAX_MARKERS + 500, 3)), cam)
    assert many.shape[0] == 3 * MAX_MARKERS


def test_edits_select_delete_undo_and_restore():
    e = Edits.of(10)
    assert e.select([1, 2, 3]) == 3
    assert e.select([3, 4], "remove") == 2 and e.selected.tolist()[:5] == [False, True, True, False, False]
    assert e.select([7], "replace") == 1
    assert e.select([1, 2]) == 3
    assert e.delete_selected() == 3 and e.num_deleted == 3 and e.num_selected == 0
    assert e.select([1, 5]) == 1  # a deleted Gaussian cannot be selected
    assert e.invert_selection() == 6 and not (e.selected & e.deleted).any() and not e.selected[5]
    e.clear_selection()
    assert e.delete_selected() == 0 and len(e.history) == 1  # nothing selected: no Undo step
    assert e.undo() and e.num_deleted == 0
    assert not e.undo()
    e.select([0]), e.delete_selected()
    assert e.restore_all() == 1 and e.num_deleted == 0
    assert e.undo() and e.deleted.tolist() == [True] + [False] * 9  # Undo takes the restore back
    with pytest.raises(ValueError):
        e.select([0], "toggle")
    e = Edits.of(6)
    e.select([1, 2]), e.delete_selected(), e.restore_all()
    e.select([1, 2, 3])
    assert e.undo() and e.selected.tolist() == [False, False, False, True, False, False]  # deleted again: unselected
    assert e.invert_selection(among=np.array([True, True, True, True, True, False])) == 2  # 0 and 4, not 5
    e = Edits.of(10)
    for i in range(UNDO_LEVELS + 5):
        e.select([i % 10]), e.delete_selected(), e.restore_all()
    assert len(e.history) == UNDO_LEVELS


@pytest.fixture()
def app(tmp_path):
    """The desktop app's state on a headless renderer (no window), on a 2000-Gaussian model."""
    from splatreel.viewer.state import AppOptions, AppState

    model = synthetic_model(2000, seed=11, sh_degree=1, radius=0.4, scale=0.02, speed=0.3)
    from splatreel.cameras import DatasetView

    ckpt = save_checkpoint(tmp_path / "m.safetensors", model, background=(1.0, 1.0, 1.0),
                           views=[DatasetView("train/r_000", orbit(20, 30, 2.0, fov_deg=40, width=64, height=64), 0.5)])
    viewer = AppState(ckpt, AppOptions(play=False))
    viewer.renderer = SplatRenderer(headless_context())
    viewer.load(str(ckpt))
    viewer.playback.time = 0.5
    assert viewer._editor.file == "m_edited.safetensors"  # in the current folder, named after the model
    viewer._editor.file = str(tmp_path / "edited.safetensors")
    yield viewer
    viewer.renderer.release()


CAM = orbit(20, 30, 2.0, fov_deg=40, width=64, height=64)


def shown_image(app) -> np.ndarray:
    app.renderer.render(CAM, 0.5, RenderSettings())
    return app.renderer.read_accumulation()


def test_app_deletes_the_selection_shows_the_rest_and_saves_it(app, tmp_path):
    model = app.model
    n = len(model)
    assert app.select_rect(CAM, 0.5, (0, 0, 24, 64)) > 20
    chosen = app._editor.edits.selected.copy()
    assert app._selection_markers(CAM).shape[0] == 3 * chosen.sum()  # all in front of the camera
    k = app.delete_selected()
    assert k == chosen.sum() and len(app.renderer.model) == n - k and app.report["deleted"] == k
    keep = torch.from_numpy(~chosen)
    expected = render_image(model.select(keep), CAM, 0.5, RenderSettings(transparent=True))
    np.testing.assert_allclose(shown_image(app), expected, atol=1e-6)  # the window shows exactly the rest
    assert not app._attempt(app.delete_selected) and "nothing is selected" in app.status

    assert app._attempt(app._undo) and len(app.renderer.model) == n
    assert not app._attempt(app._undo) and "nothing to undo" in app.status
    app._editor.edits.select(np.flatnonzero(chosen))
    app.delete_selected()
    assert app._attempt(app._save_edited)
    saved = load_checkpoint(app._editor.file)
    torch.testing.assert_close(saved.model.means, model.means[keep], rtol=0, atol=0)
    assert saved.provenance["deleted"] == {"count": int(k), "kept": n - int(k), "of": n}
    assert "crop" not in saved.provenance and saved.background == (1.0, 1.0, 1.0)
    assert [v.name for v in saved.views] == ["train/r_000"]  # the training cameras stay with the model

    # with a crop box too: the file holds the box's Gaussians less the deleted ones; the provenance says both
    app._crop.enabled, app._crop.lo, app._crop.hi = True, [-0.4, -0.4, -0.4], [0.1, 0.4, 0.4]
    app._apply_crop_edits()
    in_box = app._in_box(app._crop.shown)
    assert 0 < (in_box & chosen).sum() < k  # some deleted Gaussians lie outside the box
    app._editor.overwrite = True
    assert app._attempt(app._save_edited)
    saved = load_checkpoint(app._editor.file)
    assert len(saved.model) == int((in_box & ~chosen).sum()) == len(app.renderer.model)
    assert saved.provenance["crop"]["kept"] == int(in_box.sum())
    assert saved.provenance["deleted"] == {"count": int((in_box & chosen).sum()), "kept": len(saved.model), "of": n}


def test_app_does_not_drop_unsaved_deletions_at_the_first_open(app, tmp_path):
    other = save_checkpoint(tmp_path / "other.safetensors", synthetic_model(500, seed=2))
    app.select_rect(CAM, 0.5, (0, 0, 64, 64))
    app.delete_selected()
    deleted = app._editor.edits.num_deleted
    app._open(str(other))
    assert "not saved" in app.status and len(app.model) == 2000 and app._editor.edits.num_deleted == deleted
    assert app._drops_unsaved_edits("close the window")  # a warning about opening does not cover closing
    app._open(str(other))  # the second time goes ahead
    assert len(app.model) == 500 and app._editor.edits.num_deleted == 0
    app.select_rect(CAM, 0.5, (0, 0, 64, 64))
    app.delete_selected()
    assert app._attempt(app._save_edited), app.status  # saved: nothing to warn about
    assert not app._drops_unsaved_edits("open the file")


def test_app_keeps_its_model_and_edits_when_a_new_one_cannot_be_shown(app, tmp_path, monkeypatch):
    """A model that loads but cannot be drawn (e.g. over this GPU's texture limits) leaves the app on the model it
    showed, with its edits; opening a model never carries the overwrite tick over."""
    from splatreel.errors import GLError

    other = save_checkpoint(tmp_path / "other.safetensors", synthetic_model(500, seed=2))
    app.select_rect(CAM, 0.5, (0, 0, 32, 64))
    app.delete_selected()
    app._editor.unsaved, app._editor.overwrite = False, True
    deleted = app._editor.edits.deleted.copy()
    set_model = app.renderer.set_model

    def refuse_small(model, t=None, arrays=None):
        if len(model) == 500:
            raise GLError("too large for this GPU")
        set_model(model, t, arrays)

    monkeypatch.setattr(app.renderer, "set_model", refuse_small)
    app._open(str(other))
    assert "too large" in app.status and len(app.model) == 2000
    assert np.array_equal(app._editor.edits.deleted, deleted) and len(app.renderer.model) == 2000 - deleted.sum()
    assert app.select_rect(CAM, 0.5, (0, 0, 64, 64)) > 0  # indices still map onto what is shown
    monkeypatch.setattr(app.renderer, "set_model", set_model)
    app._open(str(other))
    assert len(app.model) == 500 and not app._editor.overwrite


def test_app_delete_from_inspect_repicks_the_pixel(app):
    """Delete in the Inspect tab removes the inspected Gaussian and inspects the same pixel again: the rest of the
    pixel's Gaussians are still there (and maybe more, reached once the deleted one no longer covers them)."""
    app.select_rect(CAM, 0.5, (0, 0, 8, 64))  # a selection made before: it survives the delete
    chosen = app._editor.edits.selected.copy()
    stack = app.inspect(CAM, 0.5, 32, 32)
    index = app._editor.shown_index
    before = {int(index[h.index]) for h in stack.hits}
    top = int(index[app._inspect.hit.index])
    assert len(before) > 2
    app._delete_inspected()
    assert app._editor.edits.deleted[top] and app._editor.edits.num_deleted == 1
    index = app._editor.shown_index
    after = {int(index[h.index]) for h in app._inspect.stack.hits}
    assert top not in after and before - {top} <= after
    assert np.array_equal(app._editor.edits.selected, chosen & ~app._editor.edits.deleted) and chosen.sum() > 0
    assert app._attempt(app._undo) and len(app.renderer.model) == 2000
    app.inspect(CAM, 0.5, 32, 32)
    app.select_inspected()
    chosen[top] = True
    assert np.array_equal(app._editor.edits.selected, chosen)  # added to what was selected


def test_a_new_model_of_the_same_size_is_sorted_anew():
    """Two crop boxes (or edits) can show as many Gaussians, laid out alike: the renderer's cached order (used by
    picks and rectangle selection) belongs to the Gaussians it was sorted for, not to their count."""
    from splatreel.viewer.renderer import SplatRenderer, headless_context

    cam = look_at((0.0, -6.0, 0.0), (0.0, 0.0, 0.0), "z", fov_deg=40, width=64, height=48)
    pair = swapping_pair()
    moved = pair.select(torch.tensor([True, True]))
    moved.means = pair.means + torch.tensor([0.0, 0.0, 0.5], dtype=pair.means.dtype)  # both higher up
    r = SplatRenderer(headless_context(), pair)
    before = r.sort(cam, 0.0).boxes[:, 1].copy()
    r.set_model(moved, 0.0)
    after = r.sort(cam, 0.0).boxes[:, 1]
    assert np.all(after < before - 1.0)  # higher up: smaller rows
    r.release()


def test_centres_follow_the_accelerations_as_the_slice_does():
    from dataclasses import replace

    model = synthetic_model(500, seed=6, speed=0.4)
    g = torch.Generator().manual_seed(2)
    model = replace(model, accelerations=torch.randn(len(model), 3, generator=g, dtype=model.means.dtype))
    rows = np.arange(0, 500, 7)
    for t in (0.1, 0.8):
        np.testing.assert_allclose(centres_at(to_arrays(model), t, rows), model.slice(t).means[rows].numpy(),
                                   atol=1e-5)
