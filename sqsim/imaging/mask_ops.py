"""One object's mask: the checks and the crop every mask model shares."""

from __future__ import annotations

import numpy as np

__all__ = ["as_mask", "mask_box"]


def as_mask(mask):
    """``mask`` (h, w), any dtype, as ``(h, w) bool`` (non-zero is True); ValueError for another shape."""
    mask = np.asarray(mask)
    if mask.ndim != 2:
        raise ValueError(f"mask must have shape (h, w), got {mask.shape}")
    return mask != 0


def mask_box(mask, margin):
    """Slices of the mask's bounding box grown by ``margin`` px (clipped to the image); None if empty."""
    rows, cols = np.nonzero(mask)
    if len(rows) == 0:
        return None
    h, w = mask.shape
    return (slice(max(rows.min() - margin, 0), min(rows.max() + margin + 1, h)),
            slice(max(cols.min() - margin, 0), min(cols.max() + margin + 1, w)))
