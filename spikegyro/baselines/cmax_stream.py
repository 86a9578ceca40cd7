"""Deprecated: moved to :mod:`spikegyro.cmax.live` and its neighbours in :mod:`spikegyro.cmax`;
this path works until the next release."""

from spikegyro.baselines.moved import forward

__getattr__ = forward(
    __name__,
    "spikegyro.cmax.live",
    "spikegyro.cmax.files",
    "spikegyro.cmax.problem",
    "spikegyro.cmax.search",
    "spikegyro.cmax.config",
)
