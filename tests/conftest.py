"""Fixtures shared by the sample tests."""

import pytest


@pytest.fixture(scope="module")
def renderer():
    """One headless `MeshRenderer` (its GL context) per test module."""
    from splatreel.samples import MeshRenderer

    r = MeshRenderer()
    yield r
    r.release()
