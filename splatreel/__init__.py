"""splatreel: a toolkit for 4D (dynamic 3D) Gaussian assets.

Core types live here and are shared by the trainer, the viewer and the exporters:
`Gaussians4D` / `KeyframedGaussians` / `SkinnedGaussians` (with ``slice(t) -> Gaussians3D``), `Camera`, and
checkpoint I/O.

Names are imported on first use (PEP 562 module ``__getattr__``, https://peps.python.org/pep-0562/), so that
``splatreel --help``, ``--version`` and ``info`` start without importing torch.
"""

from __future__ import annotations

import importlib

__version__ = "0.1.0"

_EXPORTS = {
    "cameras": ("Camera", "look_at", "orbit"),
    "checkpoint": ("Checkpoint", "load_checkpoint", "save_checkpoint"),
    "errors": ("CheckpointError", "SplatreelError"),
    "formats": ("read_checkpoint",),
    "model": ("Gaussians3D", "Gaussians4D", "KeyframedGaussians", "Model"),
    "skinned": ("SkinnedGaussians",),
}
_WHERE = {name: module for module, names in _EXPORTS.items() for name in names}

__all__ = sorted([*_WHERE, "__version__"])


def __getattr__(name: str):
    if name in _WHERE:
        value = getattr(importlib.import_module(f"{__name__}.{_WHERE[name]}"), name)
        globals()[name] = value  # later look-ups skip this function
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted({*globals(), *_WHERE})
