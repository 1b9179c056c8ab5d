"""Every sample by name: the objects (`OBJECTS`) and scenes (`SCENES`), and what is done with a name (its mesh,
bounds and centre at a time, its dataset, its exact model). The one module that knows all of them, above the
modules that define them, so that none of those imports another's registry."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .dataset import DatasetConfig, write_object_dataset
from .floor import SCENE_OBJECTS
from .gaussians import DEFAULT_FRAMES, DEFAULT_GAUSSIANS, motion_model
from .objects import Morph, SampleConfigError, SampleObject, Spinner, UnknownSampleError, Wave
from .render import MeshRenderer
from .texture import Texture
from .walker import Walker

#: Name -> object with default parameters.
OBJECTS: dict[str, SampleObject] = {o.name: o for o in (Spinner(), Wave(), Morph(), Texture(), Walker())}
#: Name -> one-line description (what ``splatreel sample --list`` prints).
SAMPLES: dict[str, str] = {name: type(o).description for name, o in OBJECTS.items()}


def get_sample(name: str) -> SampleObject:
    """The object or scene called `name` (a key of `SAMPLES` or of `SCENES`); raises `UnknownSampleError` listing
    the known names."""
    if name in OBJECTS:
        return OBJECTS[name]
    if name in SCENE_OBJECTS:
        return SCENE_OBJECTS[name]
    raise UnknownSampleError(f"unknown sample {name!r}; choose one of: {', '.join([*OBJECTS, *SCENE_OBJECTS])}")


def mesh_at(name: str, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The analytic state of sample `name` at time `t`: (vertices ``(V, 3)``, faces ``(F, 3)``, albedo
    ``(V, 3)``). Faces are the same at every t."""
    m = get_sample(name).mesh(t)
    return m.vertices, m.faces, m.colors


def object_bounds(name: str, t: float) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned box of sample `name` at time `t`: (min ``(3,)``, max ``(3,)``)."""
    return get_sample(name).mesh(t).bounds


def object_center(name: str, t: float) -> np.ndarray:
    """``(3,)`` the centre of sample `name` at time `t` (the spinner's box centre, the morph's origin, the wave's
    bounding-box centre)."""
    return get_sample(name).center(t)


def write_dataset(name: str, out: str | os.PathLike, config: DatasetConfig | None = None, force: bool = False,
                  progress: bool = False, renderer: MeshRenderer | None = None) -> Path:
    """Render sample `name` to a D-NeRF layout dataset folder `out` (atomically; see module doc).

    Args:
        name: a key of `SAMPLES`, or of `SCENES` (a scene brings its own camera rig and config type, e.g.
            ``floor`` takes a `FloorConfig`; see `splatreel.samples.floor`).
        out: destination folder; refused if it exists unless `force`.
        config: cameras, times and image size (defaults: 16 views x 16 frames at 256 px, 16 test images).
        progress: show a tqdm bar over images.
        renderer: reuse a `MeshRenderer` (its context and antialiasing); a default one is made when None.
    Returns:
        The dataset folder.
    """
    obj = get_sample(name)
    if name not in OBJECTS:  # a scene: its own rig, config and sample.json
        return obj.write_dataset(out, config, force=force, progress=progress, renderer=renderer)
    return write_object_dataset(obj, out, config, force=force, progress=progress, renderer=renderer)


def build_model(name: str, num_gaussians: int | None = None, frames: int | None = None, seed: int = 0,
                config=None):
    """A `Gaussians4D` (float32, SH degree 0, 'current' convention, time_range (0, 1)) reproducing sample `name`.

    Args:
        name: a key of `SAMPLES`, or of `SCENES` (a scene builds its own model: ``floor`` adds a static floor to
            its objects, see `splatreel.samples.floor`).
        num_gaussians: number of Gaussians in the model (points x segments; see module doc); None: the sample's
            default (`DEFAULT_GAUSSIANS` for an object).
        frames: key times ``k / (frames - 1)`` (>= 2); more keys follow curved motion more closely. None: 16 for
            an object, the dataset's frames for a scene.
        seed: random seed of the surface sampling (same seed, same model).
        config: a scene's dataset config (its camera rig decides which floor is seen); unused by objects.
    """
    if frames is not None and frames < 2:
        raise SampleConfigError(f"--time-steps must be at least 2 to build a model, got {frames}")
    if num_gaussians is not None and num_gaussians < 1:
        raise SampleConfigError(f"--gaussians must be at least 1, got {num_gaussians}")
    obj = get_sample(name)
    if name not in OBJECTS:  # a scene: its own parts and rig (as write_dataset hands scenes their own writer)
        return obj.build_model(num_gaussians, frames, seed, config)
    return motion_model(obj.mesh, DEFAULT_GAUSSIANS if num_gaussians is None else num_gaussians,
                        DEFAULT_FRAMES if frames is None else frames, seed)
