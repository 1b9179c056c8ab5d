"""Exporters: OpenUSD, per-frame meshes, per-frame 3DGS PLY.

Every exporter takes any model (`Gaussians4D`, `KeyframedGaussians`, `SkinnedGaussians`: whatever
`splatreel.formats.read_checkpoint` returns) and only calls ``model.slice(t)`` at the frame times from
`frame_times`. The formats are listed once, in the registry of `splatreel.formats` (its writers, each naming its
module here: `usd`, `mesh`, `ply`, each with ``add_args`` and ``run``), and imported when used; `exporters()` gives
them by name (the ``splatreel export`` choices).
"""

from .base import ExportError, SplatFrame, exporters, frame_times, iter_frames, slice_frame

__all__ = ["ExportError", "SplatFrame", "exporters", "frame_times", "iter_frames", "slice_frame"]
