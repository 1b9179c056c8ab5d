"""splatreel: a toolkit for 4D (dynamic 3D) Gaussian assets.

Core types live here and are shared by the trainer, the viewer and the exporters:
`Gaussians4D` / `KeyframedGaussians` (with ``slice(t) -> Gaussians3D``), `Camera`, and checkpoint I/O.
"""

__version__ = "0.1.0"

from .cameras import Camera, look_at, orbit  # noqa: E402
from .checkpoint import Checkpoint, load_checkpoint, save_checkpoint  # noqa: E402
from .errors import CheckpointError, SplatreelError  # noqa: E402
from .formats import load_model  # noqa: E402
from .model import Gaussians3D, Gaussians4D, KeyframedGaussians, Model  # noqa: E402

__all__ = ["Camera", "Checkpoint", "CheckpointError", "Gaussians3D", "Gaussians4D", "KeyframedGaussians", "Model",
           "SplatreelError", "load_checkpoint", "load_model", "look_at", "orbit", "save_checkpoint", "__version__"]
