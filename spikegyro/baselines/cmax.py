"""Deprecated: moved to :mod:`spikegyro.cmax.config` and its neighbours in :mod:`spikegyro.cmax`;
this path works until the next release."""

from spikegyro.baselines.moved import forward

__getattr__ = forward(
    __name__,
    "spikegyro.cmax.config",
    "spikegyro.cmax.problem",
    "spikegyro.cmax.search",
    "spikegyro.cmax.series",
)
