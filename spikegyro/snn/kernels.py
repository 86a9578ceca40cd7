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


# ------------------------------------------------------------------- learned time constants

TAU_MIN_MS = 0.5
"""Smallest learned time constant (ms): ε then keeps 4 taps and ν at least 3 (θ ≥ 0.1)."""

TAU_MAX_MS = 32.0
"""Largest learned time constant (ms): ε then spans 245 taps, ν 142 at θ = 0.4 (about 7.7·τs
and 4.4·τr)."""

TAU_GAIN = 20.0
"""Gain of the stored parameter (see :func:`tau_from_param`): Adam moves a parameter by about
its learning rate per step whatever the gradient's scale, so at the SNNs' 1e-4 a step moves
ln τ by up to ~2e-3 (τ by a factor e in ~500 steps) instead of ~1e-4."""


def tau_from_param(param: torch.Tensor) -> torch.Tensor:
    """Time constant τ (ms) of a stored parameter ρ, smooth and bounded:
    ln τ = ln TAU_MIN_MS + ln(TAU_MAX_MS / TAU_MIN_MS)·σ(TAU_GAIN·ρ).

    τ stays in (TAU_MIN_MS, TAU_MAX_MS), so kernels keep a sane length, and its gradient
    vanishes only smoothly towards the bounds (a clamp would stop a τ there for good).
    """
    span = math.log(TAU_MAX_MS / TAU_MIN_MS)
    return torch.exp(math.log(TAU_MIN_MS) + span * torch.sigmoid(TAU_GAIN * param))


def param_from_tau(tau: float) -> float:
    """The parameter ρ whose :func:`tau_from_param` is ``tau`` ms (inside the bounds)."""
    if not TAU_MIN_MS < tau < TAU_MAX_MS:
        raise ValueError(
            f"a learned time constant must lie in ({TAU_MIN_MS}, {TAU_MAX_MS}) ms, got {tau}"
        )
    share = math.log(tau / TAU_MIN_MS) / math.log(TAU_MAX_MS / TAU_MIN_MS)
    return math.log(share / (1.0 - share)) / TAU_GAIN


def srm_kernel_of(tau_s: torch.Tensor, *, epsilon: float = KERNEL_EPSILON) -> torch.Tensor:
    """:func:`srm_kernel` as a differentiable function of a 0-dim tensor τs (ms), in its dtype.

    The length follows the truncation rule at the current τs; the taps' derivative is taken at
    that fixed length (the rule is a step function of τs: ∂ε[k]/∂τs = ε[k]·(k − τs)/τs²).
    """
    length = srm_kernel(float(tau_s.detach()), epsilon=epsilon, dtype=torch.float64).numel()
    ratio = torch.arange(length, dtype=tau_s.dtype, device=tau_s.device) / tau_s
    return ratio * torch.exp(1.0 - ratio)


def refractory_kernel_of(
    theta: float,
    tau_r: torch.Tensor,
    *,
    scale_ref: float = 2.0,
    epsilon: float = KERNEL_EPSILON,
) -> torch.Tensor:
    """:func:`refractory_kernel` as a differentiable function of a 0-dim tensor τr (ms), at the
    length the truncation rule gives the current τr (∂ν[k]/∂τr = ν[k]·(k − 1)/τr²)."""
    length = refractory_kernel(
        theta, float(tau_r.detach()), scale_ref=scale_ref, epsilon=epsilon, dtype=torch.float64
    ).numel()
    delays = torch.arange(length - 1, dtype=tau_r.dtype, device=tau_r.device)
    taps = -scale_ref * theta * torch.exp(-delays / tau_r)
    return torch.cat([taps.new_zeros(1), taps])
