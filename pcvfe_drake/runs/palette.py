"""Colours of discovered terrain contexts, shared by the figures and the Meshcat view.

Context ids are integers >= 0; -1 is noise (no context identified) and is drawn black, as in
the paper's Fig. 4. Colours are RGB floats in [0, 1].
"""

from __future__ import annotations

import numpy as np

NOISE_RGB = (0.0, 0.0, 0.0)

# Matplotlib's tab10 without its grey (reserved) and with its red last, so the first contexts get
# well separated hues (yellow-ish first, like the paper's patchy grass).
_CONTEXT_RGB = np.array(
    [
        [0.894, 0.788, 0.176],  # yellow
        [1.000, 0.498, 0.055],  # orange
        [0.090, 0.745, 0.812],  # light blue
        [0.580, 0.404, 0.741],  # purple
        [0.173, 0.627, 0.173],  # green
        [0.122, 0.467, 0.706],  # blue
        [0.549, 0.337, 0.294],  # brown
        [0.890, 0.467, 0.761],  # pink
        [0.737, 0.741, 0.133],  # olive
        [0.839, 0.153, 0.157],  # red
    ]
)


def context_rgb(context_id: int) -> tuple[float, float, float]:
    """RGB in [0, 1] of a context id (-1 or any negative id: noise, black)."""
    k = int(context_id)
    if k < 0:
        return NOISE_RGB
    return tuple(float(c) for c in _CONTEXT_RGB[k % len(_CONTEXT_RGB)])


def context_rgb_array(context_ids: np.ndarray) -> np.ndarray:
    """(N, 3) RGB in [0, 1] for an array of context ids (vectorised ``context_rgb``)."""
    ids = np.asarray(context_ids).astype(np.int64).reshape(-1)
    out = _CONTEXT_RGB[np.mod(np.maximum(ids, 0), len(_CONTEXT_RGB))].copy()
    out[ids < 0] = NOISE_RGB
    return out
