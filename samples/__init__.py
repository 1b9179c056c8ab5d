"""Procedural animated test objects, rendered to multi-view video datasets (D-NeRF layout) or built directly into
native 4D Gaussian models.

Objects (`SAMPLES`: name -> description) are triangle meshes with per-vertex colours and a fixed topology over
scene time t in [0, 1], inside a ball of radius 0.9 (Blender world, +z up). Scenes (`SCENES`) bring their own
camera rig and config type: ``floor`` (`FloorConfig`) puts moving objects above a floor to the horizon, seen by 12
fixed cameras one per time, with alpha marking what lies nearer than a far clip (`splatreel.samples.floor`); its
model is built too: the objects from their motion plus a static floor where the rig sees it nearer than the clip.

>>> from splatreel.samples import SAMPLES, mesh_at, object_bounds, write_dataset, build_model
>>> vertices, faces, colors = mesh_at("spinner", 0.5)       # (V, 3), (F, 3), (V, 3) albedo
>>> lo, hi = object_bounds("wave", 0.25)                     # (3,), (3,)
>>> write_dataset("morph", "data/morph")                     # 16 views x 16 frames at 256 px + 16 test images
>>> write_dataset("floor", "data/floor", FloorConfig(frames=48))  # 48 frames, one camera each, + 12 test images
>>> model = build_model("spinner", num_gaussians=20000)      # Gaussians4D following the known motion
>>> exact = build_model("floor", config=FloorConfig(frames=48))  # the scene's exact model for that dataset
>>> path = trained_checkpoint("spinner")                      # bundled checkpoint trained on the spinner dataset
"""

from .catalog import OBJECTS, SAMPLES, build_model, get_sample, mesh_at, object_bounds, object_center, write_dataset
from .dataset import DatasetConfig, SampleView, test_views, train_times, train_views, transforms_json
from .floor import SCENES, FloorConfig, FloorScene
from .geometry import Mesh
from .objects import BOUNDING_RADIUS, SampleConfigError, SampleObject, UnknownSampleError
from .render import MeshRenderer, shade
from .trained import TRAINED, trained_checkpoint

__all__ = ["BOUNDING_RADIUS", "DatasetConfig", "FloorConfig", "FloorScene", "Mesh", "MeshRenderer", "OBJECTS",
           "SAMPLES", "SCENES", "SampleConfigError", "SampleObject", "SampleView", "TRAINED", "UnknownSampleError",
           "build_model", "get_sample", "mesh_at", "object_bounds", "object_center", "shade", "test_views",
           "train_times", "train_views", "trained_checkpoint", "transforms_json", "write_dataset"]
