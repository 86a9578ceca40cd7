"""Temporal kernels of the SRM neuron, sampled at Ts = 1 ms, as SLAYER computes them.

Both kernels are 1-D tensors (float32 unless asked otherwise) indexed by delay k (in time steps
of 1 ms); tap 0 is the response in the same step, so both kernels start with 0 and every spiking
layer delays its input by one step.
"""

from __future__ import annotations

import math

import torch

KERNEL_EPSILON = 0.01
"""Taps smaller than this (in potential units) are dropped, as in the official SLAYER code."""

MAX_TAPS = 10_000
"""Safety bound on kernel length (steps); time constants are a few ms."""


def srm_kernel(
    tau_s: float, *, epsilon: float = KERNEL_EPSILON, dtype: torch.dtype = torch.float32
) -> torch.Tensor:
    """Spike response (PSP) kernel ε[k] = (k/τs)·exp(1 − k/τs), k = 0, 1, 2, … (steps).

    Truncated at the first k with |ε[k]| < ``epsilon`` and k > τs (that tap excluded). The peak,
    ε[τs] = 1, is the potential one unit-weight input spike adds τs ms after it arrives.

    Args:
        tau_s: synaptic time constant τs in ms (steps), > 0.
        dtype: of the taps (float64 keeps them exact to the last bit of a double).
    """
    if not tau_s > 0:
        raise ValueError(f"tau_s must be > 0 ms, got {tau_s}")
    taps = []
    for k in range(MAX_TAPS):
        value = k / tau_s * math.exp(1.0 - k / tau_s)
        if abs(value) < epsilon and k > tau_s:
            break
        taps.append(value)
    return torch.tensor(taps, dtype=dtype)


def refractory_kernel(
    theta: float,
    tau_r: float,
    *,
    scale_ref: float = 2.0,
    epsilon: float = KERNEL_EPSILON,
    dtype: torch.dtype = torch.float32,
) -> torch.Tensor:
    """Refractory kernel ν[0] = 0, ν[k] = −scale_ref·θ·exp(−(k − 1)/τr) for k ≥ 1 (potential units).

    Added to a neuron's own membrane potential k steps after each of its spikes. Taps with
    |ν[k]| ≤ ``epsilon`` are dropped (the sequence decreases, so this truncates it).

    Args:
        theta: firing threshold θ (potential units), > 0.
        tau_r: refractory time constant τr in ms (steps), > 0.
        dtype: of the taps.
    """
    if not (theta > 0 and tau_r > 0):
        raise ValueError(f"theta and tau_r must be > 0, got theta={theta}, tau_r={tau_r}")
    taps = [0.0]
    for j in range(MAX_TAPS):
        value = -scale_ref * theta * math.exp(-j / tau_r)
        if abs(value) <= epsilon:
            break
        taps.append(value)
    return torch.tensor(taps, dtype=dtype)
