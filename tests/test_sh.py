"""SH evaluation against closed-form real spherical harmonics, orthonormality, and the cosine time terms."""

import math

import numpy as np
import pytest
import torch

from splatreel import sh


def closed_form(x, y, z):
    """Real SH (3DGS signs) written from the textbook normalisations, independent of splatreel's constants."""
    pi = math.pi
    c = lambda num, den: math.sqrt(num / (den * pi))  # noqa: E731
    return np.stack([
        np.full_like(x, 0.5 / math.sqrt(pi)),
        -c(3, 4) * y, c(3, 4) * z, -c(3, 4) * x,
        c(15, 4) * x * y, -c(15, 4) * y * z, c(5, 16) * (3 * z * z - 1), -c(15, 4) * x * z,
        c(15, 16) * (x * x - y * y),
        -c(35, 32) * y * (3 * x * x - y * y), c(105, 4) * x * y * z, -c(21, 32) * y * (5 * z * z - 1),
        c(7, 16) * z * (5 * z * z - 3), -c(21, 32) * x * (5 * z * z - 1), c(105, 16) * z * (x * x - y * y),
        -c(35, 32) * x * (x * x - 3 * y * y),
    ], -1)


def unit_dirs(n, seed=0):
    d = np.random.default_rng(seed).normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_basis_matches_closed_form_per_band(degree):
    d = unit_dirs(200)
    expected = closed_form(d[:, 0], d[:, 1], d[:, 2])[:, : (degree + 1) ** 2]
    np.testing.assert_allclose(sh.sh_basis(degree, d), expected, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(sh.sh_basis(degree, torch.from_numpy(d)).numpy(), expected, rtol=1e-12, atol=1e-12)


def test_basis_is_orthonormal_on_the_sphere():
    # Fibonacci sphere quadrature: equal-area points, integral ~ 4 pi / n * sum
    n = 20000
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    phi = math.pi * (1 + 5 ** 0.5) * i
    r = np.sqrt(1 - z * z)
    d = np.stack([r * np.cos(phi), r * np.sin(phi), z], -1)
    y = sh.sh_basis(3, d)
    gram = 4 * math.pi / n * y.T @ y
    np.testing.assert_allclose(gram, np.eye(16), atol=2e-3)


def test_eval_sh_and_rgb_conversion():
    d = unit_dirs(10)
    coeffs = np.random.default_rng(1).normal(size=(10, 16, 3))
    out = sh.eval_sh(3, coeffs, d * 3.0)  # directions need not be unit
    expected = np.einsum("nk,nkc->nc", closed_form(*d.T), coeffs)
    np.testing.assert_allclose(out, expected, rtol=1e-12)
    # lower degree ignores higher coefficients
    np.testing.assert_allclose(sh.eval_sh(1, coeffs, d), np.einsum("nk,nkc->nc", closed_form(*d.T)[:, :4],
                                                                    coeffs[:, :4]))
    rgb = np.array([[0.2, 0.5, 0.9]])
    np.testing.assert_allclose(sh.sh_to_rgb(sh.eval_sh(0, sh.rgb_to_sh(rgb)[:, None, :], d[:1])), rgb)
    assert (sh.sh_to_rgb(np.array([-3.0])) == 0).all()


def test_time_terms_are_cosines_of_relative_time():
    degree, degree_t, duration = 1, 2, 2.0
    rng = np.random.default_rng(2)
    coeffs = rng.normal(size=(5, 4 * 3, 3))
    tau = rng.normal(size=5)
    d = unit_dirs(5)
    folded = sh.collapse_time(coeffs, degree, degree_t, tau, duration)
    y = closed_form(*d.T)[:, :4]
    expected = sum(np.cos(2 * math.pi * n * tau / duration)[:, None] * np.einsum("nk,nkc->nc", y, coeffs[:, 4 * n:4 * n + 4])
                   for n in range(3))
    np.testing.assert_allclose(sh.eval_sh(degree, folded, d), expected, rtol=1e-12)
    t = torch.from_numpy(coeffs)
    np.testing.assert_allclose(sh.collapse_time(t, degree, degree_t, torch.from_numpy(tau), duration).numpy(), folded)
    with pytest.raises(ValueError):
        sh.collapse_time(coeffs, 2, 2, tau, duration)  # wrong coefficient count for these degrees
