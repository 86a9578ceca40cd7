"""Event arrays, event/gyro file readers and writers, and network input representations."""

from typing import Any

from spikegyro.events.core import EventArray, GyroTrace, Recording
from spikegyro.events.io import (
    detect_format,
    iter_event_chunks,
    read_recording,
    write_recording,
)

_TORCH_ONLY = ("accumulated_frames", "spike_tensor", "voxel_grid")

__all__ = [
    "EventArray",
    "GyroTrace",
    "Recording",
    "accumulated_frames",
    "detect_format",
    "iter_event_chunks",
    "read_recording",
    "spike_tensor",
    "voxel_grid",
    "write_recording",
]


def __getattr__(name: str) -> Any:
    # The representations compute in torch: imported on first use, so that the readers (and
    # `spikegyro predict`, which never needs them) start without importing torch.
    if name in _TORCH_ONLY:
        from spikegyro.events import representations

        return getattr(representations, name)
    raise AttributeError(f"module 'spikegyro.events' has no attribute '{name}'")
