"""What the camera-format readers share: decoded blocks, time unwrapping, reordering, rechunking.

Each camera format module (:mod:`~spikegyro.events.aedat4`, :mod:`~spikegyro.events.jaer`,
:mod:`~spikegyro.events.prophesee`, :mod:`~spikegyro.events.rosbag`) offers three functions:

- ``sniff(path, head) -> str | None``: the format's name if ``head`` (the file's first bytes)
  or the folder's content says it is one of its formats;
- ``read_header(path, fmt) -> CameraHeader``: sensor size and metadata, cheaply;
- ``iter_blocks(path, header, *, events, imu) -> Iterator[EventBlock | ImuBlock]``: the file's
  content, in file order, a bounded block at a time.

This module turns those blocks into time-sorted :class:`EventArray` chunks (in bounded memory,
tolerating packets out of order by up to ``REORDER_US``) or into a whole :class:`Recording`.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from types import ModuleType
from typing import Any

import numpy as np

from spikegyro.errors import InputError
from spikegyro.events.core import EventArray, GyroTrace, Recording
from spikegyro.events.imu import rotate_to_camera

REORDER_US = 100_000
"""How far back in time (µs) a packet may start, relative to the newest event already read,
and still be put in order while streaming. Whole-file reads sort without limit."""


@dataclass(frozen=True)
class EventBlock:
    """Decoded events in file order: x, y (px), t (µs, int64), p (0/1)."""

    x: np.ndarray
    y: np.ndarray
    t: np.ndarray
    p: np.ndarray

    def __len__(self) -> int:
        return int(self.t.shape[0])


@dataclass(frozen=True)
class ImuBlock:
    """Gyro samples: t (µs, int64) and ω (K, 3) in rad/s, in the IMU's own axes."""

    t: np.ndarray
    omega: np.ndarray


@dataclass(frozen=True)
class CameraHeader:
    """What a camera file says about itself before its data.

    Attributes:
        fmt: the format's name (as :func:`spikegyro.events.io.detect_format` gives it).
        sensor: (width, height) in pixels, or None where the file does not record it.
        attrs: metadata worth keeping (strings and numbers), e.g. the camera model.
        data_offset: byte offset of the first data byte, for formats with a text header.
        encoding: the data's encoding where a format has several (e.g. ``evt3``).
        guess_sensor: where ``sensor`` is None, a (costly) guess of it from the data, called
            only when the user gives no size.
    """

    fmt: str
    sensor: tuple[int, int] | None = None
    attrs: dict[str, Any] = field(default_factory=dict)
    data_offset: int = 0
    encoding: str = ""
    guess_sensor: Callable[[], tuple[int, int]] | None = None


def optional_import(module: str, extra: str, path: object) -> ModuleType:
    """Import an optional dependency, or raise one line naming the extra that installs it."""
    try:
        return importlib.import_module(module)
    except ImportError:
        raise InputError(
            f"{path}: this format needs the optional package '{module.split('.')[0]}': "
            f"pip install 'spikegyro[{extra}]'."
        ) from None


class TimeUnwrapper:
    """Undo the wrap-around of a counter of ``period`` ticks across successive blocks.

    A step back by more than half a period counts as one wrap (and a step forward by more than
    half a period as a late sample from before the last wrap); smaller steps back are kept (they
    are real out-of-order timestamps, put in order later).
    """

    def __init__(self, period: int) -> None:
        self.period = int(period)
        self.offset = 0
        self.last: int | None = None

    def __call__(self, raw: np.ndarray) -> np.ndarray:
        t = raw.astype(np.int64)
        if not t.size:
            return t
        prev = np.empty_like(t)
        prev[0] = t[0] if self.last is None else self.last
        prev[1:] = t[:-1]
        step = t - prev
        half = self.period // 2
        # A late sample from just before a wrap, read after one from just past it, steps forward.
        wraps = np.cumsum((step < -half).astype(np.int64) - (step > half))
        out = t + self.offset + wraps * self.period
        self.offset += int(wraps[-1]) * self.period
        self.last = int(t[-1])
        return out


def sensor_of(
    header: CameraHeader, sensor: tuple[int, int] | None, path: object
) -> tuple[int, int]:
    """The user's sensor size, else the file's (or its guess); an error when none says."""
    size = sensor or header.sensor
    if size is None and header.guess_sensor is not None:
        size = header.guess_sensor()
    if size is None:
        raise InputError(
            f"{path}: the file does not record its sensor size; pass --width and --height."
        )
    return int(size[0]), int(size[1])


def _merge(blocks: list[EventBlock]) -> EventBlock:
    if len(blocks) == 1:
        merged = blocks[0]
    else:
        merged = EventBlock(*(np.concatenate([getattr(b, k) for b in blocks]) for k in "xytp"))
    t = merged.t
    if t.size > 1 and (t[1:] < t[:-1]).any():
        order = np.argsort(t, kind="stable")
        merged = EventBlock(*(getattr(merged, k)[order] for k in "xytp"))
    return merged


def _to_array(block: EventBlock, sensor: tuple[int, int], source: str) -> EventArray:
    return EventArray.from_arrays(block.x, block.y, block.t, block.p, *sensor, source=source)


def sorted_chunks(
    blocks: Iterable[EventBlock | ImuBlock],
    sensor: tuple[int, int],
    chunk_events: int,
    source: str,
    reorder_us: int = REORDER_US,
) -> Iterator[EventArray]:
    """Time-sorted chunks of about ``chunk_events`` events from blocks in file order.

    Events are held back until no later block may precede them (``reorder_us`` behind the
    newest event), so memory stays bounded by the event rate times ``reorder_us`` plus a chunk.
    """
    pending: list[EventBlock] = []
    n_pending = 0
    flush_at = chunk_events
    emitted_t = np.iinfo(np.int64).min

    def flush(final: bool) -> Iterator[EventArray]:
        nonlocal pending, n_pending, flush_at, emitted_t
        merged = _merge(pending)
        if len(merged) and merged.t[0] < emitted_t:
            raise InputError(
                f"{source}: events arrive out of time order by more than {reorder_us / 1e3:g} ms "
                f"(t={int(merged.t[0])} us after t={emitted_t} us); the file is damaged or needs "
                "sorting (read it whole, e.g. spikegyro convert to .h5)."
            )
        cut = len(merged) if final else int(np.searchsorted(merged.t, merged.t[-1] - reorder_us))
        for i in range(0, cut, chunk_events):
            j = min(i + chunk_events, cut)
            yield _to_array(EventBlock(*(getattr(merged, k)[i:j] for k in "xytp")), sensor, source)
        if cut:
            emitted_t = int(merged.t[cut - 1])
        rest = EventBlock(*(getattr(merged, k)[cut:] for k in "xytp"))
        pending, n_pending = [rest], len(rest)
        flush_at = max(chunk_events, 2 * n_pending)

    for block in blocks:
        if not isinstance(block, EventBlock) or not len(block):
            continue
        pending.append(block)
        n_pending += len(block)
        if n_pending >= flush_at:
            yield from flush(final=False)
    if n_pending:
        yield from flush(final=True)


def gyro_from_blocks(
    blocks: Iterable[ImuBlock], imu_to_camera: np.ndarray | None, source: str
) -> GyroTrace | None:
    """All gyro samples, sorted by time, rotated into the camera frame; None if there are none."""
    blocks = [b for b in blocks if len(b.t)]
    if not blocks:
        return None
    t = np.concatenate([b.t for b in blocks])
    omega = np.concatenate([b.omega for b in blocks])
    order = np.argsort(t, kind="stable")
    return GyroTrace.from_arrays(
        t[order], rotate_to_camera(omega[order], imu_to_camera), source=source
    )


def recording_from_blocks(
    blocks: Iterable[EventBlock | ImuBlock],
    header: CameraHeader,
    sensor: tuple[int, int] | None,
    imu_to_camera: np.ndarray | None,
    source: str,
) -> Recording:
    """The whole file in memory: events sorted by time, gyro in the camera frame."""
    size = sensor_of(header, sensor, source)
    events: list[EventBlock] = []
    imu: list[ImuBlock] = []
    for block in blocks:
        (events if isinstance(block, EventBlock) else imu).append(block)
    events = [b for b in events if len(b)]
    ev = _to_array(_merge(events), size, source) if events else EventArray.empty(*size)
    attrs = dict(header.attrs, source_format=header.fmt)
    return Recording(events=ev, gyro=gyro_from_blocks(imu, imu_to_camera, source), attrs=attrs)
