"""Stateful, event-driven streaming inference for real-time prediction.

- :mod:`spikegyro.stream.stateful`: ``StreamingSNN`` runs an SRM network 1 ms per step with state
  carried across calls, equal to the batch forward (exact recursions for the truncated kernels).
- :mod:`spikegyro.stream.model`: ``spec_from_model`` / ``load_streaming_model`` (checkpoint ->
  engine, torch-free once the checkpoint's spec is cached); ``DEFAULT_CHECKPOINT`` is the shipped
  pretrained SNN-6.
- :mod:`spikegyro.stream.engine`: ``load_engine``, either engine of ``predict``.
- :mod:`spikegyro.stream.predict`: ``predict_stream`` (file -> reprojection -> 1 ms bins -> engine
  -> prediction file, flat memory), ``event_mapper``, ``model_camera``, ``ErrorStats``.
- :mod:`spikegyro.stream.batched`: the ``--device`` path of ``predict``: segments with warm-up
  context, binned and run in batches on a torch device (GPU throughput, approximate).
- :mod:`spikegyro.stream.writer`: prediction files (CSV/HDF5), also used by the baselines.
- :mod:`spikegyro.stream.console`: what the streaming commands share (options, progress bar).

``spikegyro predict`` itself is in :mod:`spikegyro.cmax.commands`: it chooses between the SNN and
contrast maximization, which is built on this package.

The writer API is re-exported lazily, so importing a submodule (e.g. the engine, to load a
cached network without torch) does not pull in the event readers.
"""

from __future__ import annotations

from typing import Any

__all__ = ["PredictionWriter", "read_predictions", "write_predictions"]


def __getattr__(name: str) -> Any:
    if name in __all__:
        from spikegyro.stream import writer

        return getattr(writer, name)
    raise AttributeError(f"module 'spikegyro.stream' has no attribute '{name}'")
