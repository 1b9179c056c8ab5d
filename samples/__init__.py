"""Procedural animated test objects rendered to datasets in the D-NeRF layout."""
