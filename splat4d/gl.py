"""OpenGL plumbing shared by everything that draws: headless (EGL) contexts and GLSL program loading.

Shaders live in ``shaders/`` (installed as the package ``splat4d.shaders``), one ``.glsl`` file per program with
``#if defined VERTEX_SHADER`` / ``#if defined FRAGMENT_SHADER`` sections (the moderngl-window layout).
`preprocess` puts ``#version`` first, then the stage define, the rendering constants of `splat4d.constants`
(so GLSL uses the same numbers as the CPU rasterizer) and caller defines, then ``#line`` so compiler errors point
at the right line of the file.
"""

from __future__ import annotations

import re
from importlib import resources
from typing import Mapping

from .constants import GLSL_DEFINES
from .errors import GLError

STAGES = ("VERTEX_SHADER", "GEOMETRY_SHADER", "FRAGMENT_SHADER")


class ShaderError(GLError):
    """A shader file is malformed or failed to compile."""


def shader_source(name: str) -> str:
    """Text of ``shaders/<name>.glsl``."""
    fname = name if name.endswith(".glsl") else f"{name}.glsl"
    try:
        return resources.files("splat4d.shaders").joinpath(fname).read_text()
    except FileNotFoundError:
        raise ShaderError(f"shader {fname} not found in splat4d.shaders") from None


def _glsl_value(v: object) -> str:
    if isinstance(v, bool):
        return "1" if v else "0"
    if isinstance(v, float):
        return repr(float(v)) if "e" not in repr(v) else f"{v:.9e}"
    return str(v)


def preprocess(source: str, stage: str, defines: Mapping[str, object] | None = None, name: str = "<string>") -> str:
    """Source for one stage: ``#version`` line, stage + constant + caller defines, ``#line 2``, the rest."""
    if stage not in STAGES:
        raise ShaderError(f"unknown shader stage {stage!r}")
    lines = source.splitlines()
    first = next((i for i, l in enumerate(lines) if l.strip()), None)
    if first is None or not re.match(r"\s*#version\s+\d+", lines[first]):
        raise ShaderError(f"{name}: the first line must be a #version directive")
    all_defines: dict[str, object] = {stage: 1, **GLSL_DEFINES, **(defines or {})}
    head = [lines[first]] + [f"#define {k} {_glsl_value(v)}" for k, v in all_defines.items()]
    return "\n".join(head + [f"#line {first + 2}"] + lines[first + 1:]) + "\n"


def stages_in(source: str) -> list[str]:
    return [s for s in STAGES if re.search(rf"defined\s*\(?\s*{s}\b", source)]


def load_program(ctx, name: str, defines: Mapping[str, object] | None = None, **kwargs):
    """Compile ``shaders/<name>.glsl`` into a moderngl Program (extra kwargs go to ``ctx.program``)."""
    source = shader_source(name)
    st = stages_in(source)
    if "VERTEX_SHADER" not in st:
        raise ShaderError(f"{name}.glsl has no VERTEX_SHADER section")
    parts = {s.split("_")[0].lower() + "_shader": preprocess(source, s, defines, name) for s in st}
    try:
        return ctx.program(**parts, **kwargs)
    except Exception as exc:  # moderngl.Error carries the driver's log
        raise ShaderError(f"{name}.glsl failed to compile: {str(exc).strip()}") from None


def create_headless_context(require: int = 330):
    """A standalone OpenGL context with no display, through EGL (Mesa llvmpipe on machines without a GPU)."""
    try:
        import moderngl
    except ImportError as exc:  # pragma: no cover - moderngl is a core dependency
        raise GLError(f"moderngl is not installed ({exc})") from None
    errors = []
    for kwargs in ({"backend": "egl"}, {}):
        try:
            return moderngl.create_standalone_context(require=require, **kwargs)
        except Exception as exc:
            errors.append(f"{kwargs.get('backend', 'default')}: {str(exc).strip().splitlines()[0]}")
    raise GLError("no headless OpenGL context (install Mesa EGL: apt-get install libegl1 libgl1-mesa-dri): "
                  + "; ".join(errors))
