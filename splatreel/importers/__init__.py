"""Importers: other tools' 4D / 3D Gaussian files as splatreel models.

Every command that takes a model calls `splatreel.formats.read_checkpoint(path, **options)`; the readers below are
registered there the first time it runs, and are chosen by content:

=====================  ===========================================================  =============================
reader                 accepts                                                      model
=====================  ===========================================================  =============================
``4dgs-checkpoint``    official 4DGS ``chkpnt*.pth`` (capture tuple + iteration),    `Gaussians4D`
                       Efficient4D ``model.pth`` (bare tuple), or their folder
``deformation-folder`` 4DGaussians / 4DGen output folder, ``iteration_N`` folder     `KeyframedGaussians` (baked)
                       or ``deformation.pth``
``ply``                one 3DGS PLY (SH degree 0-3, binary or ASCII)                  static `Gaussians4D`
``ply-sequence``       a folder or glob of per-frame 3DGS PLYs                       `KeyframedGaussians`
=====================  ===========================================================  =============================

Command-line tools add the import options with `add_import_args(parser)` and pass `import_options(args)` to
`read_checkpoint`. What an importer assumed is printed (one line, stderr) and stored in ``provenance["assumed"]``.
Pickles are loaded without executing code (`safe_load.safe_torch_load`).
"""

from __future__ import annotations

from .options import IMPORT_OPTIONS, add_import_args, check_options, import_options

__all__ = ["IMPORT_OPTIONS", "add_import_args", "check_options", "import_options", "register"]

_registered = False


def register() -> None:
    """Register the importers' readers with `splatreel.formats` (idempotent)."""
    global _registered
    if _registered:
        return
    from pathlib import Path

    from ..formats import Reader, register_reader
    from . import deformation, official, ply

    def is_sequence(path: Path) -> bool:
        if not path.exists():
            return ply.has_glob(str(path))
        return path.is_dir() and not deformation.sniff(path) and any(
            p.suffix.lower() == ".ply" for p in path.iterdir())

    # Sniffs are mutually exclusive; registration order does not matter.
    register_reader(Reader("ply-sequence", "folder or glob of per-frame 3DGS PLY files", is_sequence,
                           ply.read_ply_sequence))
    register_reader(Reader("ply", "3DGS PLY (SH degree 0-3, binary or ASCII)",
                           lambda p: p.is_file() and ply.is_ply(p), ply.read_ply_model))
    register_reader(Reader("deformation-folder", "4DGaussians / 4DGen output folder (point_cloud.ply + "
                           "deformation.pth)", deformation.sniff, deformation.read_deformation_folder))
    register_reader(Reader("4dgs-checkpoint", "official 4DGS chkpnt*.pth / Efficient4D model.pth", official.sniff,
                           official.read_official))
    _registered = True
