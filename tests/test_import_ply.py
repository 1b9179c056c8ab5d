"""3DGS PLY files (static) and PLY sequences (keyframes)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from test_import_helpers import random_splats, rotation_3d_reference, write_splat_ply

from splatreel.errors import CheckpointError
from splatreel.formats import read_checkpoint


def _sigmoid(x):
    return 1 / (1 + np.exp(-x))


@pytest.mark.parametrize("fmt", ["binary_little_endian", "ascii", "binary_big_endian"])
@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_ply_round_trip_renders_the_file_values(tmp_path, fmt, degree):
    s = random_splats(7, degree, seed=degree)
    path = write_splat_ply(tmp_path / "point_cloud.ply", **s, fmt=fmt)
    ckpt = read_checkpoint(path)
    model = ckpt.model
    assert model.kind == "gaussians4d" and model.sh_degree == degree and len(model) == 7
    for t in (0.0, 0.37, 1.0):
        g = model.slice(t)
        assert bool(g.visible.all())
        np.testing.assert_allclose(g.means.numpy(), s["means"], atol=1e-6)
        np.testing.assert_allclose(g.velocities.numpy(), 0.0, atol=1e-6)
        for i in range(7):
            r = rotation_3d_reference(s["quats"][i])
            cov = r @ np.diag(np.exp(s["log_scales"][i]) ** 2) @ r.T
            np.testing.assert_allclose(g.covariances[i].numpy(), cov, atol=1e-6)
        np.testing.assert_allclose(g.opacities.numpy(), _sigmoid(s["opacity_logits"]), atol=1e-6)
        np.testing.assert_allclose(g.sh.numpy(), s["sh"], atol=1e-6)  # channel-major f_rest unpacked
    assert ckpt.provenance["reader"] == "ply"


def test_f_rest_is_channel_major(tmp_path):
    s = random_splats(1, 1)
    s["sh"][:] = 0
    s["sh"][0, 1] = [1.0, 2.0, 3.0]  # coefficient 1 of R, G, B -> f_rest_0, f_rest_3, f_rest_6
    path = write_splat_ply(tmp_path / "a.ply", **s)
    text = path.read_bytes()
    assert b"property float f_rest_8" in text
    assert read_checkpoint(path).model.sh_dc.shape == (1, 1, 3)
    torch.testing.assert_close(read_checkpoint(path).model.sh_rest[0, 0], torch.tensor([1.0, 2.0, 3.0]))


def test_sh_degree_option_truncates(tmp_path):
    path = write_splat_ply(tmp_path / "a.ply", **random_splats(3, 3))
    model = read_checkpoint(path, sh_degree=1).model
    assert model.sh_degree == 1 and model.sh_rest.shape == (3, 3, 3)
    with pytest.raises(CheckpointError, match="above"):
        read_checkpoint(write_splat_ply(tmp_path / "b.ply", **random_splats(3, 0)), sh_degree=2)


def test_sequence_folder_and_glob_become_keyframes(tmp_path):
    frames = [random_splats(5, 1, seed=i) for i in range(3)]
    for i, s in enumerate(frames):
        write_splat_ply(tmp_path / f"time_{i * 5}.ply", **s)  # natural order: 0, 5, 10
    for source in (tmp_path, str(tmp_path / "time_*.ply")):
        ckpt = read_checkpoint(source, time_range=(1.0, 3.0))
        model = ckpt.model
        assert model.kind == "keyframed" and model.num_frames == 3
        torch.testing.assert_close(model.times, torch.tensor([1.0, 2.0, 3.0]))
        for i, t in enumerate([1.0, 2.0, 3.0]):
            g = model.slice(t)
            np.testing.assert_allclose(g.means.numpy(), frames[i]["means"], atol=1e-6)
            np.testing.assert_allclose(g.opacities.numpy(), _sigmoid(frames[i]["opacity_logits"]), atol=1e-6)
            np.testing.assert_allclose(g.scales.numpy(), np.exp(frames[i]["log_scales"]), atol=1e-6)
        mid = model.slice(1.5).means.numpy()
        np.testing.assert_allclose(mid, 0.5 * (frames[0]["means"] + frames[1]["means"]), atol=1e-6)
        assert ckpt.provenance["reader"] == "ply-sequence" and ckpt.provenance["assumed"][0].startswith("--back")


def test_sequence_with_different_counts_is_refused(tmp_path):
    write_splat_ply(tmp_path / "f0.ply", **random_splats(5, 0))
    write_splat_ply(tmp_path / "f1.ply", **random_splats(4, 0))
    with pytest.raises(CheckpointError, match=r"f1\.ply: 4 Gaussians, but f0\.ply has 5"):
        read_checkpoint(tmp_path)


def test_glob_matching_nothing(tmp_path):
    with pytest.raises(CheckpointError, match="matches no PLY files"):
        read_checkpoint(str(tmp_path / "nothing_*.ply"))


def test_plain_point_cloud_ply_is_refused(tmp_path):
    path = tmp_path / "points3d.ply"
    header = "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n" \
             "property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n"
    path.write_text(header + "0 0 0 255 0 0\n1 1 1 0 255 0\n")
    with pytest.raises(CheckpointError, match="plain point cloud"):
        read_checkpoint(path)


def test_truncated_and_corrupt_ply(tmp_path):
    path = write_splat_ply(tmp_path / "a.ply", **random_splats(10, 2))
    path.write_bytes(path.read_bytes()[:-40])
    with pytest.raises(CheckpointError, match="truncated PLY"):
        read_checkpoint(path)
    s = random_splats(2, 0)
    s["means"][1, 0] = np.nan
    with pytest.raises(CheckpointError, match="NaN"):
        read_checkpoint(write_splat_ply(tmp_path / "nan.ply", **s))


def test_sequence_times_from_manifest(tmp_path):
    names = []
    for i in range(3):
        names.append(f"frame_{i:06d}.ply")
        write_splat_ply(tmp_path / names[-1], **random_splats(2, 0, seed=i))
    frames = [{"index": i, "time": t, "file": n} for i, (t, n) in enumerate(zip([0.5, 0.75, 2.0], names))]
    (tmp_path / "manifest.json").write_text(json.dumps({"format": "3dgs-ply-sequence", "frames": frames}))
    ckpt = read_checkpoint(tmp_path)
    torch.testing.assert_close(ckpt.model.times, torch.tensor([0.5, 0.75, 2.0]))
    assert ckpt.provenance["times_from"] == "manifest.json"
    assert not any(a.startswith("--time-range") for a in ckpt.provenance["assumed"])
    torch.testing.assert_close(read_checkpoint(tmp_path, time_range=(0, 1)).model.times, torch.tensor([0.0, 0.5, 1.0]))


def test_round_trip_through_splatreel_export_ply(tmp_path):
    """`splatreel export ply` frames read back as keyframes that match the model at those times."""
    from splatreel.export.ply import write_ply_sequence
    from splatreel.model import static_gaussians4d

    s = random_splats(6, 0, seed=4)
    model = static_gaussians4d(torch.tensor(s["means"], dtype=torch.float32),
                               torch.exp(torch.tensor(s["log_scales"], dtype=torch.float32)),
                               torch.tensor(s["quats"], dtype=torch.float32),
                               torch.sigmoid(torch.tensor(s["opacity_logits"], dtype=torch.float32)),
                               torch.rand(6, 3), time_range=(0.0, 2.0))
    model.t_means[:3] = 1.8  # three of them fade in late: invisible at t = 0
    model.log_t_scales[:3] = np.log(0.3)
    times = [0.0, 1.0, 2.0]
    write_ply_sequence(model, tmp_path / "frames", times)
    back = read_checkpoint(tmp_path / "frames").model
    torch.testing.assert_close(back.times, torch.tensor(times))
    for t in times:
        ref, got = model.slice(t), back.slice(t)
        torch.testing.assert_close(got.means, ref.means, atol=1e-5, rtol=0)
        torch.testing.assert_close(got.covariances, ref.covariances, atol=1e-5, rtol=0)
        torch.testing.assert_close(got.opacities, torch.where(ref.visible, ref.opacities, 0.0), atol=2e-6, rtol=0)
        torch.testing.assert_close(got.sh, ref.sh, atol=1e-5, rtol=0)


@pytest.mark.parametrize("degree", [0, 2])
def test_empty_ply_reads_as_an_empty_model(tmp_path, degree):
    s = random_splats(0, degree)
    model = read_checkpoint(write_splat_ply(tmp_path / "empty.ply", **s)).model
    assert len(model) == 0 and model.sh_degree == degree


def test_a_frame_with_nothing_visible_exports_as_an_empty_ply(tmp_path):
    """--drop-invisible at a time when every Gaussian has faded out: an empty file, not a crash."""
    from splatreel.export.ply import write_ply_sequence
    from splatreel.model import static_gaussians4d

    s = random_splats(4, 1, seed=5)
    model = static_gaussians4d(torch.tensor(s["means"], dtype=torch.float32),
                               torch.exp(torch.tensor(s["log_scales"], dtype=torch.float32)),
                               torch.tensor(s["quats"], dtype=torch.float32), torch.full((4,), 0.5),
                               torch.rand(4, 3), time_range=(0.0, 1.0))
    model.t_means[:] = 0.0
    model.log_t_scales[:] = np.log(0.05)  # gone long before t = 1
    paths = write_ply_sequence(model, tmp_path / "frames", [0.0, 1.0], drop_invisible=True)
    assert len(read_checkpoint(paths[1]).model) == 0 and len(read_checkpoint(paths[0]).model) == 4


def test_binary_ply_with_a_list_element_before_the_vertices(tmp_path):
    """plyfile reads any element layout: a binary file whose ``face`` element (a list property) comes before the
    vertices still gives the splats."""
    src = write_splat_ply(tmp_path / "a.ply", **random_splats(3, 0, seed=2))
    data = src.read_bytes()
    head, body = data.split(b"end_header\n", 1)
    head = head.replace(b"element vertex", b"element face 1\nproperty list uchar int vertex_indices\nelement vertex")
    face = np.array([3], "<u1").tobytes() + np.array([0, 1, 2], "<i4").tobytes()
    (tmp_path / "b.ply").write_bytes(head + b"end_header\n" + face + body)
    torch.testing.assert_close(read_checkpoint(tmp_path / "b.ply").model.means, read_checkpoint(src).model.means)
