"""Deprecated: moved to :mod:`spikegyro.cmax.iwe` and its neighbours in :mod:`spikegyro.cmax`;
this path works until the next release."""

from spikegyro.baselines.moved import forward

__getattr__ = forward(
    __name__,
    "spikegyro.cmax.iwe",
)
