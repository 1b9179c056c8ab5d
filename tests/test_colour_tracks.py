"""Groups of control nodes that the model's motion loses, found again by their colour in the images
(`splatreel.train.colour_tracks`), on the floor scene filmed one camera per time, whose pendulum's motion is known."""

import math

import numpy as np
import pytest
import torch

from splatreel import quaternion
from splatreel.samples.floor import FloorScene
from splatreel.samples.geometry import axis_angle_matrix
from splatreel.train.colour_tracks import follow_lost_groups, frame_images
from splatreel.train.data import load_dataset
from splatreel.train.nodes import TrackedNodes

from conftest import sample_dataset


@pytest.fixture(scope="module")
def floor(tmp_path_factory):
    """The floor scene, 96 frames at 120 px: each of the 12 cameras sees 8 frames, as in the bench's floor."""
    return load_dataset(sample_dataset(tmp_path_factory, "floor", frames=96, size=120, test_views=1))


def bob_centre(scene: FloorScene, t: float) -> np.ndarray:
    """The pendulum bob's centre at time t (the sample's geometry: pivot, swing about +y, rod length)."""
    return np.asarray(scene.pivot) + axis_angle_matrix((0.0, 1.0, 0.0), scene.swing(t)) @ [0.0, 0.0,
                                                                                           -scene.pendulum_length]


def nodes(positions: np.ndarray, middle: int, still: np.ndarray) -> TrackedNodes:
    f, m = positions.shape[:2]
    identity = quaternion.from_rotmat(torch.eye(3, dtype=torch.float64).expand(f * m, 3, 3).contiguous())
    return TrackedNodes(torch.from_numpy(positions), identity.reshape(f, m, 4), middle, torch.from_numpy(still))


def test_a_lost_pendulum_bob_is_found_by_its_colour_and_the_still_node_on_it_joins(floor):
    """Nodes on the bob at the middle frame, tracked as if the bob stood still (lost: the model's motion had no bob to
    follow), move with the true bob once followed by colour, within a fifth of the bob's travel; a node on the bob
    pinned as still joins them; the pinned nodes on the floor, far from any part, stay put."""
    scene = FloorScene()
    times = np.asarray(floor.frame_times)
    mid = len(times) // 2
    truth = np.stack([bob_centre(scene, t) for t in times])
    offsets = np.array([[0.04, 0.0, 0.05], [-0.04, 0.03, 0.05], [0.0, -0.04, 0.06], [0.0, 0.0, -0.1]])
    on_bob = truth[mid] + offsets  # the last one pinned as still
    grid = np.stack(np.meshgrid(np.linspace(-3.0, 3.0, 9), np.linspace(2.5, 4.5, 4), indexing="ij"), -1)
    floor_nodes = np.concatenate([grid.reshape(-1, 2), np.full((36, 1), scene.floor_z)], 1)
    canonical = np.concatenate([on_bob, floor_nodes])
    still = np.r_[np.zeros(3, bool), np.ones(1 + len(floor_nodes), bool)]
    lost = nodes(np.repeat(canonical[None], len(times), 0), mid, still)

    found = follow_lost_groups(lost, floor, torch.ones(3))
    assert found.taken == 1 and found.joined == 1
    moved = found.nodes.positions.numpy()
    travel = np.linalg.norm(truth - truth[mid], axis=1)
    assert travel.max() > 1.0  # the bob swings far: held still, the nodes are lost
    error = np.linalg.norm(moved[:, :4].mean(1) - (truth + offsets.mean(0)), axis=1)
    assert error.mean() < 0.2 * travel.mean(), (error.mean(), travel.mean())
    assert np.linalg.norm(moved[:, :4].mean(1) - canonical[:4].mean(0), axis=1).mean() > 0.5 * travel.mean()
    assert not bool(found.nodes.still[3]) and bool(found.nodes.still[4:].all())
    np.testing.assert_array_equal(moved[:, 4:], lost.positions.numpy()[:, 4:])
    np.testing.assert_array_equal(moved[mid], canonical)  # the canonical frame stays


def test_a_group_tracked_on_its_part_is_left_alone_and_a_matrix_is_not_searched(floor, tmp_path_factory):
    """Nodes that follow the bob already (tracked right) keep their tracks; with several views a time (an image
    matrix) there is no camera's median image of one camera per time, and nothing changes."""
    scene = FloorScene()
    times = np.asarray(floor.frame_times)
    mid = len(times) // 2
    truth = np.stack([bob_centre(scene, t) for t in times])
    offsets = np.array([[0.04, 0.0, 0.05], [-0.04, 0.03, 0.05], [0.0, -0.04, 0.06]])
    right = nodes(truth[:, None] + offsets[None], mid, np.zeros(3, bool))
    found = follow_lost_groups(right, floor, torch.ones(3))
    assert found.taken == 0
    torch.testing.assert_close(found.nodes.positions, right.positions, rtol=0, atol=0)

    matrix = load_dataset(sample_dataset(tmp_path_factory, "spinner", views=2, frames=4, size=32, test_views=1))
    assert frame_images(matrix, torch.ones(3)) is None
    spinner_nodes = nodes(np.zeros((4, 3, 3)) + np.arange(3)[None, :, None] * 0.1, 2, np.zeros(3, bool))
    assert follow_lost_groups(spinner_nodes, matrix, torch.ones(3)).nodes is spinner_nodes


def test_train_says_how_many_lost_groups_it_found_again():
    from splatreel.cli.train import node_outcome_line

    outcome = {"template": False, "template_ratio": None, "tracked_by": "motion"}
    plain = node_outcome_line(outcome, "nodes")
    assert plain.startswith("control nodes tracked by the model's own motion") and "colour" not in plain
    line = node_outcome_line({**outcome, "colour_tracks": {"groups": 1, "joined": 2}}, "nodes")
    assert line.startswith(plain) and line.endswith(
        "; 1 group of nodes it lost found again by colour in the images (2 nodes pinned as still joined)")
    assert node_outcome_line({**outcome, "colour_tracks": {"groups": 0, "joined": 0}}, "nodes") == plain
