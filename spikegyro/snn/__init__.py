"""SRM spiking neurons with SLAYER-style surrogate gradients.

``kernels`` (ε, ν), ``functional`` (psp, spike_fn, surrogate_gradient, fire, conv_over_time) and
``layers`` (SRMParams, SRMConv, SRMDense, GASP). Spike trains are (N, C, H, W, T), time last,
1 ms per step.
"""

from spikegyro.snn.functional import conv_over_time, fire, psp, spike_fn, surrogate_gradient
from spikegyro.snn.kernels import refractory_kernel, srm_kernel
from spikegyro.snn.layers import GASP, SRMConv, SRMDense, SRMParams

__all__ = [
    "GASP",
    "SRMConv",
    "SRMDense",
    "SRMParams",
    "conv_over_time",
    "fire",
    "psp",
    "refractory_kernel",
    "spike_fn",
    "srm_kernel",
    "surrogate_gradient",
]
