"""Stateful, event-driven streaming inference for real-time prediction.

- :mod:`spikegyro.stream.stateful`: ``StreamingSNN`` runs an SRM network 1 ms per step with state
  carried across calls, equal to the batch forward (exact recursions for the truncated kernels).
- :mod:`spikegyro.stream.model`: ``spec_from_model`` / ``load_streaming_model`` (checkpoint ->
  engine); ``DEFAULT_CHECKPOINT`` is the shipped pretrained SNN-6.
- :mod:`spikegyro.stream.predict`: ``predict_stream`` (file -> reprojection -> 1 ms bins -> engine
  -> prediction file, flat memory), ``event_mapper``, ``model_camera``, ``ErrorStats``.
- :mod:`spikegyro.stream.writer`: prediction files (CSV/HDF5), also used by the baselines.
- :mod:`spikegyro.stream.commands`: ``spikegyro predict``.

Only the light writer API is imported here, so baselines can write predictions without loading
the network code.
"""

from spikegyro.stream.writer import PredictionWriter, read_predictions, write_predictions

__all__ = ["PredictionWriter", "read_predictions", "write_predictions"]
