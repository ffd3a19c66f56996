"""Numbers for JSON output (no pydrake): NaN and infinities become ``None`` (JSON null)."""

from __future__ import annotations

import math


def finite_or_none(x) -> float | None:
    """``float(x)``, or ``None`` where ``x`` is None, NaN or infinite."""
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None
