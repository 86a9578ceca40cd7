"""spikegyro: an event camera as a gyroscope, with spiking neural networks."""

__version__ = "0.1.0"
