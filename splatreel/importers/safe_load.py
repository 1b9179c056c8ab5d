"""Load PyTorch pickles (``.pth``) without running code from them.

Official 4DGS / Efficient4D checkpoints and 4DGaussians / 4DGen ``deformation.pth`` files are pickles. A pickle
can call any importable function while it loads, so these files are read with ``torch.load(weights_only=True)``:
only tensors, containers and numbers are rebuilt, plus an allow-list of the numpy globals those files contain
(``spatial_lr_scale`` is a ``numpy.float64``; the Adam learning rates of the ``xyz`` and ``t`` groups are numpy
floats). Files written under numpy 1.x name the scalar constructor ``numpy.core.multiarray.scalar``, numpy 2.x
``numpy._core.multiarray.scalar``: both names are allowed. Anything else (``os.system``, ``builtins.eval``, an
arbitrary class) is refused with one line naming it, before any of it is unpickled.
"""

from __future__ import annotations

import pickle
import re
import zipfile
from pathlib import Path
from typing import Any

from ..errors import CheckpointError


def _allowed_globals() -> list:
    """The numpy globals that a data-only pickle may use, under every name numpy 1.x and 2.x pickle them."""
    import numpy as np

    try:
        from numpy._core import multiarray  # numpy >= 2
    except ImportError:  # pragma: no cover - numpy 1.x
        from numpy.core import multiarray
    allowed: list = [np.dtype, np.ndarray]
    for module in ("numpy.core.multiarray", "numpy._core.multiarray"):
        allowed.append((multiarray.scalar, f"{module}.scalar"))
        allowed.append((multiarray._reconstruct, f"{module}._reconstruct"))
    dtypes = getattr(np, "dtypes", None)
    if dtypes is not None:  # numpy >= 1.25 pickles dtypes through their DType classes
        for name in ("Float16DType", "Float32DType", "Float64DType", "LongDoubleDType", "Int8DType", "Int16DType",
                     "Int32DType", "Int64DType", "UInt8DType", "UInt16DType", "UInt32DType", "UInt64DType",
                     "BoolDType", "LongDType", "ULongDType", "LongLongDType", "ULongLongDType"):
            if hasattr(dtypes, name):
                allowed.append(getattr(dtypes, name))
    return allowed


def _global_name(entry) -> str:
    if isinstance(entry, tuple):
        return entry[1]
    return f"{entry.__module__}.{entry.__qualname__}"


def _refuse(path: Path, names: list[str]) -> CheckpointError:
    shown = ", ".join(names[:3]) + (f" and {len(names) - 3} more" if len(names) > 3 else "")
    return CheckpointError(f"{path}: refused to load: the pickle needs {shown}, which is not a tensor, number or "
                           f"numpy scalar (splatreel never runs code from a model file; re-save it with tensors "
                           f"only)")


def safe_torch_load(path: Path) -> Any:
    """The object stored in a ``torch.save`` file, rebuilt without executing code from it (on the CPU).

    Raises CheckpointError (one line, naming the file) when the file is unreadable or needs a global outside
    the allow-list.
    """
    import torch

    path = Path(path)
    allowed = _allowed_globals()
    allowed_names = {_global_name(a) for a in allowed}
    if zipfile.is_zipfile(path):
        # Scan the pickle's globals first: a refusal then names every offender and nothing is unpickled.
        try:
            needed = torch.serialization.get_unsafe_globals_in_checkpoint(str(path))
        except Exception:  # noqa: BLE001 - a damaged archive is reported by torch.load below
            needed = []
        bad = [g for g in needed if g not in allowed_names]
        if bad:
            raise _refuse(path, bad)
    try:
        with torch.serialization.safe_globals(allowed):
            return torch.load(str(path), map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as exc:
        found = re.findall(r"GLOBAL ([\w.]+)", str(exc))
        if found or "Unsupported" in str(exc) or "global" in str(exc).lower():
            raise _refuse(path, found or ["a global that is not allowed"]) from None
        raise CheckpointError(f"{path}: not a readable PyTorch file ({_first_line(exc)})") from None
    except (RuntimeError, EOFError, OSError, ValueError, zipfile.BadZipFile, KeyError, AttributeError,
            TypeError, IndexError) as exc:
        raise CheckpointError(f"{path}: not a readable PyTorch file (truncated, corrupted or another format: "
                              f"{_first_line(exc)})") from None


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0][:200] if text else type(exc).__name__
