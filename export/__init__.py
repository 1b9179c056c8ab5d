"""Exporters: OpenUSD, per-frame meshes, per-frame 3DGS PLY.

Every exporter takes any model (`Gaussians4D`, `KeyframedGaussians`, whatever `splatreel.formats.read_checkpoint`
returns) and only calls ``model.slice(t)`` at the frame times from `frame_times`. Importing this package registers the
built-in formats; `exporters()` lists them (the ``splatreel export`` choices come from it).
"""

from .base import (ExportError, Exporter, SplatFrame, exporters, frame_times, iter_frames, register_exporter,
                   slice_frame)
from . import usd, mesh, ply  # noqa: E402,F401  (register the built-in formats)

__all__ = ["ExportError", "Exporter", "SplatFrame", "exporters", "frame_times", "iter_frames", "register_exporter",
           "slice_frame", "usd", "mesh", "ply"]
