"""The engine that ``predict`` runs a checkpoint with: the exact event-driven stream, or the
batched torch path on a device.

Above both :mod:`spikegyro.stream.model` (torch-free once the spec is cached) and
:mod:`spikegyro.stream.batched` (torch), so that choosing between them imports torch only when
the batched path is chosen.
"""

from __future__ import annotations

import os
import sys
from typing import Any

from spikegyro.pretrained import resolve_checkpoint
from spikegyro.stream.model import BatchedOnly, load_streaming_model
from spikegyro.stream.predict import PredictorFactory
from spikegyro.stream.stateful import StreamingSNN


def load_engine(
    path: str | os.PathLike,
    device: str = "stream",
    threads: int = 1,
    segment_ms: int = 400,
    context_ms: int = 100,
    batch: int | None = None,
) -> tuple[StreamingSNN | PredictorFactory, dict[str, Any]]:
    """A checkpoint's network as ``predict`` runs it, and its metadata: on ``device="stream"``
    the exact event-driven engine on ``threads`` CPU threads, else (a torch device) the batched
    approximate path, segments of ``segment_ms`` after ``context_ms`` of warm-up, ``batch``
    segments a pass (None: from memory)."""
    path = resolve_checkpoint(path)
    if device == "stream":
        try:
            return load_streaming_model(path, threads=threads)
        except BatchedOnly as exc:
            print(f"{exc}: running it on the batched path (--device cpu).", file=sys.stderr)
            device = "cpu"
    # torch is imported only here: the exact stream needs none once the spec is cached
    from spikegyro.stream.batched import SegmentConfig, batched_predictor

    return batched_predictor(path, device, SegmentConfig(segment_ms, context_ms, batch))
