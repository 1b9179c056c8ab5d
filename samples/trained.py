"""Trained checkpoints shipped with the package: ``splatreel train`` (the default auto recipe, 600 iterations) fitted
to a procedural sample.

They give the viewer, the exporters, their tests and first-time users a real trained model without training one.
`scripts/bundle_sample.sh` regenerates them (the sample's default dataset, seed 0); each checkpoint's metadata
records how it was made (``splatreel info``).
"""

from __future__ import annotations

from pathlib import Path

from splatreel.errors import SplatreelError

#: Samples with a trained checkpoint in this package.
TRAINED: tuple[str, ...] = ("spinner",)


def trained_checkpoint(name: str = "spinner") -> Path:
    """Path of the bundled trained checkpoint of sample `name` (see `TRAINED`)."""
    if name not in TRAINED:
        raise SplatreelError(f"no trained checkpoint is bundled for sample {name!r}; bundled: {', '.join(TRAINED)}")
    path = Path(__file__).resolve().parent / f"{name}.safetensors"
    if not path.is_file():
        raise SplatreelError(f"the bundled checkpoint {path} is missing from this installation; "
                           "run `bash scripts/bundle_sample.sh` in a source checkout to make it")
    return path
