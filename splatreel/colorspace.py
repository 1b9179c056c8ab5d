"""The sRGB transfer function (IEC 61966-2-1), the one place colour is encoded or decoded.

A 3DGS model's colours are sRGB-encoded display values: it is fitted to ordinary (sRGB) photographs, and its
rasterizer blends those values directly. Formats whose specifications say *linear* (OpenEXR readers, USD
``displayColor``, glTF ``COLOR_0``) get them decoded with `srgb_to_linear`.
"""

from __future__ import annotations

import numpy as np


def srgb_to_linear(c: np.ndarray, clip: bool = True) -> np.ndarray:
    """sRGB-encoded values -> linear light (same shape, float32).

    With ``clip`` the input is clamped to [0, 1] first; without, negatives become 0 and values above 1 follow the
    curve's power segment (EXR keeps them).
    """
    c = np.clip(c, 0.0, 1.0) if clip else np.maximum(c, 0.0)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4).astype(np.float32)


def linear_to_srgb(c: np.ndarray) -> np.ndarray:
    """Linear light in [0, 1] -> sRGB-encoded values (clamped; float32): the inverse of `srgb_to_linear`."""
    c = np.clip(c, 0.0, 1.0)
    return np.where(c <= 0.0031308, c * 12.92, 1.055 * c ** (1 / 2.4) - 0.055).astype(np.float32)


def premultiplied_to_linear(rgba: np.ndarray) -> np.ndarray:
    """``[..., 4]`` premultiplied sRGB-encoded RGBA -> premultiplied *linear* RGBA (alpha unchanged).

    The colour is decoded unpremultiplied (colour / alpha), then multiplied by alpha again: decoding the
    premultiplied value would darken every partly transparent pixel.
    """
    alpha = rgba[..., 3:4]
    straight = np.where(alpha > 1e-8, rgba[..., :3] / np.maximum(alpha, 1e-8), 0.0)
    return np.concatenate([srgb_to_linear(straight, clip=False) * alpha, alpha], -1).astype(np.float32)
