"""ComfyUI's MASK means 1 − alpha: LoadImage gives 1 − the file's alpha, and a 64×64 zero mask for
an image without one; JoinImageWithAlpha takes alpha = 1 − mask. NumPy only, so that it is
tested without torch."""

from __future__ import annotations

from typing import Optional, Tuple

import numpy as np


def alpha_codes(mask: np.ndarray, size: Tuple[int, int]) -> Optional[np.ndarray]:
    """The 16-bit alpha of one [H, W] MASK for an image of `size` (H, W), or None where the mask
    says the image is opaque everywhere (all zero: LoadImage's 64×64 stand-in for an image
    without alpha, or a mask of the image's size with nothing masked)."""
    mask = np.asarray(mask, dtype=np.float32)
    if not mask.any():
        return None
    if mask.shape != tuple(size):
        raise ValueError(
            f"matup: the mask is {mask.shape[1]}×{mask.shape[0]} but the base colour is "
            f"{size[1]}×{size[0]}: give the mask of the image it belongs to"
        )
    return np.round((1.0 - np.clip(mask, 0.0, 1.0)) * 65535.0).astype(np.uint16)


def mask_of(alpha: Optional[np.ndarray], size: Tuple[int, int]) -> np.ndarray:
    """The [H, W] MASK of 16-bit (or 8-bit) alpha codes, zeros (opaque) where there is none."""
    if alpha is None:
        return np.zeros(size, np.float32)
    scale = 65535.0 if alpha.dtype == np.uint16 else 255.0
    return (1.0 - alpha.astype(np.float32) / scale).astype(np.float32)
