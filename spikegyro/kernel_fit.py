"""The SRM kernels in closed form from their taps, so that compiled code can run them as
recursions: the PSP kernel ε[k] = c·k·pᵏ and the refractory kernel ν[k] = a·q^(k−1).

NumPy only: the streaming runtime runs without torch, and the CPU training engine shares it.
"""

from __future__ import annotations

import numpy as np


def fit_alpha_kernel(kernel: np.ndarray, name: str = "srm kernel") -> tuple[float, float]:
    """(c, p) with ``kernel[k] == c k p^k`` for every tap; raises ValueError if no such pair."""
    kernel = np.asarray(kernel, dtype=np.float64)
    if kernel.size < 3 or kernel[0] != 0 or kernel[1] <= 0:
        raise ValueError(f"{name}: expected c k p^k with at least 3 taps, got {kernel[:4]}")
    p = kernel[2] / (2.0 * kernel[1])
    c = kernel[1] / p
    k = np.arange(kernel.size)
    if not np.allclose(kernel, c * k * p**k, rtol=1e-5, atol=1e-7):
        raise ValueError(f"{name}: taps are not of the form c k p^k; cannot run it recursively")
    return float(c), float(p)


def fit_exp_kernel(kernel: np.ndarray, name: str = "refractory kernel") -> tuple[float, float]:
    """(a, q) with ``kernel[0] == 0`` and ``kernel[k] == a q^(k-1)`` for k >= 1."""
    kernel = np.asarray(kernel, dtype=np.float64)
    if kernel.size < 2 or kernel[0] != 0:
        raise ValueError(f"{name}: expected nu[0] = 0 then a q^(k-1), got {kernel[:4]}")
    a = kernel[1]
    q = kernel[2] / a if kernel.size > 2 else 0.0
    k = np.arange(1, kernel.size)
    if not np.allclose(kernel[1:], a * q ** (k - 1), rtol=1e-5, atol=1e-7):
        raise ValueError(f"{name}: taps are not of the form a q^(k-1); cannot run it recursively")
    return float(a), float(q)
