"""OpenGL plumbing shared by everything that draws: headless (EGL) contexts and GLSL program loading.

Shaders live in ``shaders/`` (installed as the package ``splatreel.shaders``), one ``.glsl`` file per program with
``#if defined VERTEX_SHADER`` / ``#if defined FRAGMENT_SHADER`` sections (the moderngl-window layout).
`preprocess` puts ``#version`` first, then the stage define, the rendering constants of `splatreel.constants`
(so GLSL uses the same numbers as the CPU rasterizer) and caller defines, then ``#line`` so compiler errors point
at the right line of the file.
"""

from __future__ import annotations

import ctypes
import functools
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
        return resources.files("splatreel.shaders").joinpath(fname).read_text()
    except FileNotFoundError:
        raise ShaderError(f"shader {fname} not found in splatreel.shaders") from None


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
    body = []
    for number, line in enumerate(lines[first + 1:], first + 2):
        included = re.match(r'\s*#include\s+"([\w.]+)"\s*$', line)
        if included:  # a shared part (shaders/<name>.glsl), then the line numbers of this file again
            body += ["#line 1", shader_source(included.group(1)), f"#line {number + 1}"]
        else:
            body.append(line)
    return "\n".join(head + [f"#line {first + 2}"] + body) + "\n"


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


class EGLCurrent:
    """Save and restore whichever EGL context is current (e.g. another library's), around our own GL work.

    moderngl's ``with ctx`` makes `ctx` current but on exit leaves *no* EGL context current instead of the previous
    one, which breaks code that relies on its own standalone context staying current.
    """

    _lib = None

    def __init__(self) -> None:
        lib = self._load()
        self.saved = None
        if lib is not None and lib.eglGetCurrentContext():
            self.saved = (lib.eglGetCurrentDisplay(), lib.eglGetCurrentSurface(0x3059),  # EGL_DRAW
                          lib.eglGetCurrentSurface(0x305A), lib.eglGetCurrentContext())  # EGL_READ

    def restore(self) -> None:
        if self.saved is not None:
            self._lib.eglMakeCurrent(*self.saved)

    @classmethod
    def _load(cls):
        if cls._lib is None:
            try:
                lib = ctypes.CDLL("libEGL.so.1")
            except OSError:
                cls._lib = False
                return None
            for name in ("eglGetCurrentContext", "eglGetCurrentDisplay", "eglGetCurrentSurface"):
                getattr(lib, name).restype = ctypes.c_void_p
            lib.eglGetCurrentSurface.argtypes = [ctypes.c_int]
            lib.eglMakeCurrent.argtypes = [ctypes.c_void_p] * 4
            lib.eglMakeCurrent.restype = ctypes.c_uint
            cls._lib = lib
        return cls._lib or None


def with_context(method):
    """Run a method with the renderer's context current, then give the previous EGL context back.

    Several standalone contexts may live in one process and moderngl sends calls to whichever is current, not to
    the object's own; so GL work is bracketed by ``with ctx`` (once: nesting a moderngl context is not supported).
    """

    @functools.wraps(method)
    def wrapper(self, *args, **kwargs):
        if getattr(self, "_gl_depth", 0):
            return method(self, *args, **kwargs)
        previous = EGLCurrent()
        self._gl_depth = 1
        try:
            with self.ctx:
                return method(self, *args, **kwargs)
        finally:
            self._gl_depth = 0
            previous.restore()

    return wrapper
