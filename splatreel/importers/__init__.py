"""Importers: other tools' 4D / 3D Gaussian files as splatreel models.

Every command that takes a model calls `splatreel.formats.read_checkpoint(path, **options)`; the registry there lists
the readers below (by dotted path, imported when used), and chooses one by content:

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

from pathlib import Path

from .options import IMPORT_OPTIONS, add_import_args, check_options, import_options

__all__ = ["IMPORT_OPTIONS", "add_import_args", "check_options", "import_options", "sniff_ply_sequence"]


def sniff_ply_sequence(path: Path) -> bool:
    """A glob pattern, or a folder holding PLY files that is not a 4DGaussians iteration folder (which holds
    ``point_cloud.ply`` beside ``deformation.pth``): the ``ply-sequence`` reader of `splatreel.formats`."""
    from . import deformation, ply

    if not path.exists():
        return ply.has_glob(str(path))
    return path.is_dir() and not deformation.sniff(path) and any(p.suffix.lower() == ".ply" for p in path.iterdir())
