"""Small statistics shared by the instrument and the acquisition layers.

Neutral ground: the head device pools repeated readings with :func:`pooled_mean`, and nothing
here knows of devices, plans or datasets.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["pooled_mean"]


def pooled_mean(means, stds, ns) -> tuple[float, float, int]:
    """Pool repeated averages: ``(mean, standard error of the mean, total n)``.

    The pooled variance is ``[sum (n_k - 1) s_k^2 + n_k (m_k - M)^2] / (N - 1)`` and the
    standard error ``sqrt(var / N)``.

    Examples
    --------
    >>> pooled_mean([1.0, 3.0], [0.0, 0.0], [1, 1])
    (2.0, 1.0, 2)
    """
    m = np.asarray(means, dtype=float)
    s = np.asarray(stds, dtype=float)
    n = np.asarray(ns, dtype=float)
    total = float(n.sum())
    mean = float(np.sum(n * m) / total)
    if total <= 1:
        return mean, float(s.max(initial=0.0)), int(total)
    var = float(np.sum((n - 1) * s**2 + n * (m - mean) ** 2) / (total - 1))
    return mean, math.sqrt(var / total), int(total)
