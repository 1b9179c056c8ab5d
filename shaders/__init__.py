"""GLSL programs (``*.glsl``), loaded with `splatreel.gl.load_program`."""
