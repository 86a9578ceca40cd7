"""Stateful, event-driven streaming inference for real-time prediction."""

from spikegyro.stream.writer import PredictionWriter, read_predictions, write_predictions

__all__ = ["PredictionWriter", "read_predictions", "write_predictions"]
