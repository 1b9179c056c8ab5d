"""GLSL programs (``*.glsl``), loaded with `splat4d.gl.load_program`."""
