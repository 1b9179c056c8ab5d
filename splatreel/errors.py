"""Typed errors raised by library code.

Library functions raise these; only the CLI (`splatreel.cli.main`) turns them into a one-line message and an
exit code. Every message names the file or the argument at fault and says what was expected.
"""

from __future__ import annotations


class SplatreelError(Exception):
    """Base class: a problem with the user's input that deserves a one-line message, not a traceback."""


class CheckpointError(SplatreelError):
    """A checkpoint is missing, truncated, corrupted, of an unknown version or holds invalid values."""


class ModelError(SplatreelError):
    """Model tensors have inconsistent shapes, wrong dtypes or non-finite values."""


class DatasetError(SplatreelError):
    """A dataset folder is missing, empty, unreadable or inconsistent."""


class OutputExistsError(SplatreelError):
    """An output already exists and `force` was not given."""


class OutputWriteError(SplatreelError):
    """An output cannot be written: a read-only or full disk, no permission, a file where a folder should be."""


class CameraError(SplatreelError):
    """A camera or camera-path description is invalid."""


class GLError(SplatreelError):
    """No usable OpenGL context (EGL or window), or a shader failed to compile."""
