"""Exporters: OpenUSD, per-frame meshes, per-frame 3DGS PLY."""
