"""Small image operations shared by the feature backends and the 2D line detector."""

from __future__ import annotations

import numpy as np


def stretch_contrast(gray: np.ndarray, low: float = 1.0, high: float = 99.0) -> np.ndarray:
    """Linearly map the ``low``-``high`` percentile grey levels to 0-255 (uint8).

    LSD's gradient threshold is absolute, so a washed-out image (gamma 0.2) or a dark one loses
    its lines; an affine stretch restores the gradients without changing their directions.
    """
    lo, hi = np.percentile(gray, [low, high])
    if hi - lo < 1.0:
        return gray
    out = (gray.astype(np.float32) - lo) * (255.0 / (hi - lo))
    return np.clip(out, 0, 255).astype(np.uint8)
