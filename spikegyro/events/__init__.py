"""Event arrays, event/gyro file readers and writers, and network input representations."""

from spikegyro.events.core import EventArray, GyroTrace, Recording
from spikegyro.events.io import (
    detect_format,
    iter_event_chunks,
    read_recording,
    write_recording,
)
from spikegyro.events.representations import (
    accumulated_frames,
    spike_tensor,
    voxel_grid,
)

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
