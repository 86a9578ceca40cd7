"""Dataset windows and how a window becomes a network input and a training target.

A *window* is ``window_ms`` milliseconds of events cut from a sequence file (or from a freshly
simulated sequence), with the ground-truth angular velocity at the end of every 1 ms bin: bin k
covers ``[t_start + k ms, t_start + (k + 1) ms)`` and its label is ω(t_start + (k + 1) ms), as in
the paper's official data loader.

How a window is encoded depends on the checkpoint's ``input_spec`` dict (see
:mod:`spikegyro.models.registry`), so training, evaluation and prediction share one code path:

- ``"spikes"`` (SNN-6): a binary (2, H, W, T) spike tensor; the target is ω per step, (3, T).
- ``"voxel"`` / ``"frames"`` (ANNs): one input per non-overlapping ``target_ms`` sub-window,
  (S, C, H, W) with S = window_ms / target_ms; the target is the mean ω over each sub-window,
  (S, 3). Predictions are held over their sub-window to compare per millisecond with the SNN.

Training batches travel one of two ways (``TrainConfig.data_path``): *dense*, each window encoded
by :func:`encode_window` in a DataLoader worker and the stacked tensors copied to the device; or
*events*, each window's (augmented, rescaled) events sent as an :class:`EventBatch` of flat event
lists and binned on the device by :func:`encode_batch` (:mod:`spikegyro.events.binning_torch`):
~1 MB per 100 ms window instead of a 35 MB float32 spike tensor at 240x180. Both give the same
input tensors. For the event-driven CPU engine, spike batches arriving as events are binned into
a sparse tensor instead (:func:`spikegyro.events.binning_torch.spike_tensor` with ``sparse``),
which that engine reads without ever making the dense one.
"""

from __future__ import annotations

import functools
import hashlib
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any, Protocol, cast

import numpy as np
import torch
from torch.utils.data import Dataset

from spikegyro.errors import InputError
from spikegyro.events import binning_torch
from spikegyro.events.clock import Clock, close_steps, mean_rates, step_begins, virtual_times
from spikegyro.events.core import EventArray, GyroTrace, Recording
from spikegyro.events.io import Hdf5Index, index_hdf5, read_hdf5_span, read_recording
from spikegyro.events.representations import accumulated_frames, spike_tensor, voxel_grids

BIN_US = 1000
SPLITS = ("train", "val", "test")
REPRESENTATIONS = ("spikes", "voxel", "frames")
DATA_PATHS = ("auto", "events", "dense")


@dataclass(frozen=True)
class Window:
    """One fixed-length slice of a sequence with per-millisecond ground truth.

    Attributes:
        events: the events with ``t_start_us <= t < t_start_us + window_ms * 1000`` (absolute
            timestamps, microseconds, as in the source file).
        t_start_us: start of the window, microseconds.
        omega: (T, 3) ground-truth angular velocity in rad/s at the end of each 1 ms bin,
            i.e. at ``t_start_us + (k + 1) * 1000``.
        omega_start: (3,) angular velocity at ``t_start_us`` itself, rad/s (time inversion
            needs it: it becomes the label of the last bin).
        source: the sequence file (or a description of a simulated sequence).
        index: the window's position in its sequence (0..4 for the fixed test windows) or the
            sample number for random training windows.
        step_us: on the event clock (:mod:`spikegyro.events.clock`), the real length of each
            step, µs (T,); the events' times are then the network's own (step k is virtual
            millisecond k) and ``omega`` is the mean ω over each step times its length over
            1 ms, the rotation per virtual millisecond the network answers. None: 1 ms bins.
    """

    events: EventArray
    t_start_us: int
    omega: np.ndarray
    omega_start: np.ndarray
    source: str = ""
    index: int = 0
    step_us: np.ndarray | None = None

    @property
    def rates(self) -> np.ndarray:
        """(T,) factor from the network's output (and ``omega``) to rad/s at each step."""
        if self.step_us is None:
            return np.ones(self.num_steps)
        return BIN_US / np.maximum(np.asarray(self.step_us, np.float64), 1.0)

    @property
    def num_steps(self) -> int:
        """Number of 1 ms bins T."""
        return int(self.omega.shape[0])

    @property
    def window_ms(self) -> int:
        """Window length in milliseconds (= T)."""
        return self.num_steps

    @property
    def t_end_us(self) -> int:
        """End of the window (exclusive), microseconds."""
        return self.t_start_us + self.num_steps * BIN_US


@dataclass(frozen=True)
class InputSpec:
    """Typed view of a checkpoint's ``input`` dict.

    Attributes:
        representation: "spikes", "voxel" or "frames".
        sensor: (width, height) in pixels of the events the model expects before scaling.
        scale: factor applied to event coordinates before binning (0.5: 240x180 -> 120x90).
        window_ms: window length, milliseconds.
        output: "per_step" (ω every ms) or "window_mean" (mean ω per ``target_ms`` window).
        num_bins: voxel-grid time bins (voxel only).
        target_ms: length of the sub-windows an ANN predicts the mean over, milliseconds.
        clock: the SNN's clock as :meth:`Clock.as_dict` gives it; None: the paper's 1 ms steps
            (on the event clock ``window_ms`` counts steps).
    """

    representation: str = "spikes"
    sensor: tuple[int, int] = (240, 180)
    scale: float = 1.0
    window_ms: int = 100
    output: str = "per_step"
    num_bins: int = 5
    target_ms: int = 20
    clock: dict[str, int] | None = None

    @property
    def step_clock(self) -> Clock:
        """The network's clock (:class:`~spikegyro.events.clock.Clock`)."""
        return Clock.from_dict(self.clock)

    def __post_init__(self) -> None:
        if not self.step_clock.is_paper and self.representation != "spikes":
            raise InputError(
                f"the event clock drives spiking networks; a {self.representation} input "
                "keeps the paper's clock (drop --clock)."
            )
        if self.representation not in REPRESENTATIONS:
            raise InputError(
                f"input representation '{self.representation}': choose one of "
                f"{', '.join(REPRESENTATIONS)}."
            )
        if self.output not in ("per_step", "window_mean"):
            raise InputError(f"input output '{self.output}': use per_step or window_mean.")
        if self.output == "window_mean" and self.window_ms % self.target_ms:
            raise InputError(
                f"window of {self.window_ms} ms is not a multiple of the {self.target_ms} ms "
                "target windows; choose --target-ms dividing --window-ms."
            )

    @classmethod
    def from_dict(cls, spec: dict[str, Any]) -> InputSpec:
        known = {k: v for k, v in spec.items() if k in cls.__dataclass_fields__}
        if "sensor" in known:
            known["sensor"] = tuple(int(v) for v in known["sensor"])
        return cls(**known)

    @classmethod
    def for_representation(
        cls,
        representation: str,
        *,
        sensor: tuple[int, int],
        scale: float,
        window_ms: int,
        num_bins: int = 5,
        target_ms: int = 20,
        clock: Clock | None = None,
    ) -> InputSpec:
        """The spec a model of this input kind is trained with (SNN: per step, ANN: means)."""
        output = "per_step" if representation == "spikes" else "window_mean"
        steps = None if clock is None or clock.is_paper else clock.as_dict()
        return cls(
            representation, tuple(sensor), scale, window_ms, output, num_bins, target_ms, steps
        )

    def as_dict(self) -> dict[str, Any]:
        out = asdict(self)
        out["sensor"] = list(self.sensor)
        if out["clock"] is None:
            del out["clock"]  # checkpoints of the paper's clock read as before
        return out

    @property
    def in_channels(self) -> int:
        """Input planes of an ANN for this representation."""
        return {"spikes": 2, "voxel": self.num_bins, "frames": 2}[self.representation]


def with_clock(spec: InputSpec, clock: Clock) -> InputSpec:
    """The spec with the network run on ``clock`` instead of its own."""
    return replace(spec, clock=None if clock.is_paper else clock.as_dict())


def as_input_spec(spec: InputSpec | dict[str, Any]) -> InputSpec:
    """Accept either the typed spec or the checkpoint's plain dict."""
    return spec if isinstance(spec, InputSpec) else InputSpec.from_dict(spec)


# ---------------------------------------------------------------------------------- windows


def window_at(
    rec: Recording, t_start_us: int, window_ms: int, *, source: str = "", index: int = 0
) -> Window:
    """Cut ``window_ms`` ms starting at ``t_start_us`` (µs) out of a recording with ground truth."""
    if rec.gyro is None or len(rec.gyro) < 2:
        raise InputError(f"{source}: the sequence has no ground-truth angular velocity.")
    t_end_us = t_start_us + window_ms * BIN_US
    ends = t_start_us + BIN_US * np.arange(1, window_ms + 1)
    return Window(
        events=rec.events.slice_time(t_start_us, t_end_us),
        t_start_us=int(t_start_us),
        omega=rec.gyro.interpolate(ends).astype(np.float32),
        omega_start=rec.gyro.interpolate(np.array([t_start_us]))[0].astype(np.float32),
        source=source,
        index=index,
    )


def sequence_span_us(rec: Recording, source: str = "") -> tuple[int, int]:
    """(first, last) ground-truth time of a sequence, microseconds: where windows may lie."""
    if rec.gyro is None or len(rec.gyro) < 2:
        raise InputError(f"{source}: the sequence has no ground-truth angular velocity (ang_xyz).")
    return int(rec.gyro.t[0]), int(rec.gyro.t[-1])


def sequence_windows(rec: Recording, window_ms: int, source: str = "") -> list[Window]:
    """The non-overlapping windows tiling a sequence from its first ground-truth sample."""
    t0, t1 = sequence_span_us(rec, source)
    count = (t1 - t0) // (window_ms * BIN_US)
    return [
        window_at(rec, t0 + i * window_ms * BIN_US, window_ms, source=source, index=i)
        for i in range(count)
    ]


def random_start(rec: Recording, window_ms: int, rng: np.random.Generator, source: str) -> int:
    """Start (µs) of a window at a uniformly random whole millisecond inside the sequence."""
    t0, t1 = sequence_span_us(rec, source)
    slots = (t1 - t0) // BIN_US - window_ms
    if slots < 0:
        raise InputError(
            f"{source or 'sequence'}: {(t1 - t0) / 1000:.0f} ms long, shorter than the "
            f"{window_ms} ms window."
        )
    return t0 + int(rng.integers(0, slots + 1)) * BIN_US


def random_window(rec: Recording, window_ms: int, rng: np.random.Generator, **kw: Any) -> Window:
    """A window starting at a uniformly random whole millisecond inside the sequence."""
    start = random_start(rec, window_ms, rng, kw.get("source", ""))
    return window_at(rec, start, window_ms, **kw)


def steps_window(
    events: EventArray, gyro: GyroTrace | None, begin_us: int, ends_us: np.ndarray,
    cuts: np.ndarray, *, source: str = "", index: int = 0,
) -> Window:  # fmt: skip
    """The window of event-clock steps ``ends_us`` from ``begin_us`` (µs; step k holds
    ``events[cuts[k-1]:cuts[k]]``, :func:`~spikegyro.events.clock.close_steps`), in the
    network's own time, labelled with each step's mean ω times its length over 1 ms (NaN
    without a ``gyro``)."""
    events = events[: int(cuts[-1])]
    begins = step_begins(ends_us, begin_us)
    step_us = (ends_us - begins).astype(np.int64)
    if gyro is None:
        labels = np.full((len(ends_us), 3), np.nan)
    else:
        labels = mean_rates(gyro.t, gyro.omega, begins, ends_us) * (step_us / BIN_US)[:, None]
    virtual = replace(events, t=virtual_times(events.t, ends_us, cuts, begin_us))
    return Window(
        events=virtual, t_start_us=0, omega=labels.astype(np.float32),
        omega_start=labels[0].astype(np.float32), source=source, index=index, step_us=step_us,
    )  # fmt: skip


def clocked_window(
    read: Callable[[int, int], EventArray], gyro: GyroTrace | None, begin_us: int, known_us: int,
    num_steps: int, clock: Clock, *, source: str = "", index: int = 0,
) -> Window | None:  # fmt: skip
    """``num_steps`` steps of the event clock from ``begin_us`` as a :func:`steps_window`;
    ``read(a, b)`` gives the events in ``[a, b)`` µs, all known up to ``known_us``. None where
    the sequence ends first. Reads spans that double until the steps close."""
    length = max(num_steps * clock.min_step_us, 50 * BIN_US)
    while True:
        stop = min(begin_us + length, known_us + 1)
        events = read(begin_us, stop)
        ends, cuts = close_steps(events.t, begin_us, clock, known_us=stop - 1, max_steps=num_steps)
        if len(ends) == num_steps:
            return steps_window(events, gyro, begin_us, ends, cuts, source=source, index=index)
        if stop > known_us:
            return None
        length *= 2


def clocked_sequence_windows(
    rec: Recording, num_steps: int, clock: Clock, source: str = ""
) -> list[Window]:
    """The consecutive windows of ``num_steps`` event-clock steps tiling a sequence from its
    first ground-truth sample (the event clock's :func:`sequence_windows`)."""
    t0, t1 = sequence_span_us(rec, source)
    events = rec.events.slice_time(t0, t1 + 1)
    ends, cuts = close_steps(events.t, t0, clock, known_us=t1)
    windows = []
    for i in range(len(ends) // num_steps):
        k = slice(i * num_steps, (i + 1) * num_steps)
        first = int(cuts[i * num_steps - 1]) if i else 0
        begin = int(ends[i * num_steps - 1]) if i else t0
        windows.append(steps_window(events[first:], rec.gyro, begin, ends[k], cuts[k] - first,
                                    source=source, index=i))  # fmt: skip
    return windows


def draw_clocked(
    sequence: Callable[[], tuple[Recording, Callable[[int, int], EventArray], str]],
    num_steps: int, clock: Clock, rng: np.random.Generator, index: int, tries: int = 20,
) -> Window:  # fmt: skip
    """A window of ``num_steps`` event-clock steps from a random whole millisecond of a random
    sequence (``sequence()`` -> (recording with its ground truth, ``read(a, b)``, name)),
    drawing again where the sequence ends before the steps close."""
    for _ in range(tries):
        rec, read, source = sequence()
        t0, t1 = sequence_span_us(rec, source)
        slots = (t1 - t0 - num_steps * clock.min_step_us) // BIN_US
        if slots < 0:
            continue
        start = t0 + int(rng.integers(0, slots + 1)) * BIN_US
        window = clocked_window(read, rec.gyro, start, t1, num_steps, clock, source=source,
                                index=index)  # fmt: skip
        if window is not None:
            return window
    raise InputError(
        f"{tries} random windows of {num_steps} steps ({clock.label}) ran past the end of their "
        "sequences; simulate longer sequences (--duration-ms) or use fewer steps per window."
    )


def split_files(data_dir: str | Path, split: str) -> list[Path]:
    """Sorted sequence files ``data_dir/split/*.h5``; InputError if there are none."""
    if split not in SPLITS:
        raise InputError(f"split '{split}': choose one of {', '.join(SPLITS)}.")
    folder = Path(data_dir) / split
    files = sorted(folder.glob("*.h5")) + sorted(folder.glob("*.hdf5"))
    if not files:
        raise InputError(
            f"{folder}: no .h5 sequence files; create a dataset with `spikegyro simulate` "
            "(layout DIR/{train,val,test}/seq_*.h5)."
        )
    return files


@functools.cache
def sequence_index(path: str) -> Hdf5Index:
    """A sequence file's time index and ground truth, memoised per process (DataLoader workers
    each keep their own: about 10 kB per 500 ms sequence)."""
    return index_hdf5(path)


def fixed_windows(
    data_dir: str | Path, split: str, window_ms: int = 100, clock: Clock | None = None
) -> list[Window]:
    """The evaluation windows of a split: each sequence cut into non-overlapping windows.

    A 500 ms sequence gives five 100 ms windows, as in the official test set. On an event
    ``clock`` the windows are of ``window_ms`` steps.
    """
    windows: list[Window] = []
    for path in split_files(data_dir, split):
        rec = read_recording(path)
        if clock is None or clock.is_paper:
            windows.extend(sequence_windows(rec, window_ms, str(path)))
        else:
            windows.extend(clocked_sequence_windows(rec, window_ms, clock, str(path)))
    return windows


# --------------------------------------------------------------------------------- encoding


def windows_fingerprint(windows: list[Window]) -> str:
    """A short hash identifying a list of windows by their data (source, start, events, ω).

    Training keeps the best validation score with the fingerprint of the windows it was
    measured on, so a resumed run on other data starts its best-checkpoint record afresh.
    """
    digest = hashlib.sha256()
    for w in windows:
        digest.update(f"{w.source}|{w.t_start_us}|{len(w.events)}|".encode())
        digest.update(np.ascontiguousarray(w.omega, dtype=np.float64).tobytes())
    return digest.hexdigest()[:16]


def _scaled_events(window: Window, spec: InputSpec) -> EventArray:
    events = window.events
    if (events.width, events.height) != tuple(spec.sensor):
        raise InputError(
            f"{window.source}: events from a {events.width}x{events.height} sensor, but the model "
            f"expects {spec.sensor[0]}x{spec.sensor[1]}; rescale or crop the events first."
        )
    return events if spec.scale == 1.0 else events.rescale(spec.scale)


def _model_events(window: Window, spec: InputSpec) -> EventArray:
    """The window's events on the model's sensor, after checking the window length."""
    if window.num_steps != spec.window_ms:
        raise InputError(
            f"{window.source}: a {window.num_steps} ms window, but the model takes "
            f"{spec.window_ms} ms windows."
        )
    return _scaled_events(window, spec)


def encode_window(window: Window, input_spec: InputSpec | dict[str, Any]) -> torch.Tensor:
    """The network input for one window (float32, CPU).

    Returns:
        spikes: (2, H, W, T) binary spike tensor (channel 0 OFF, 1 ON).
        voxel: (S, num_bins, H, W), one voxel grid per ``target_ms`` sub-window.
        frames: (S, 2, H, W), accumulated-event frames per sub-window.
    """
    spec = as_input_spec(input_spec)
    ev = _model_events(window, spec)
    width, height = ev.width, ev.height
    if spec.representation == "spikes":
        return torch.from_numpy(
            spike_tensor(
                ev.x, ev.y, ev.t, ev.p, height=height, width=width,
                t_start_us=window.t_start_us, num_bins=window.num_steps,
            )
        )  # fmt: skip
    sub_us = spec.target_ms * BIN_US
    count = spec.window_ms // spec.target_ms
    if spec.representation == "voxel":  # one pass over the events for all sub-windows
        return torch.from_numpy(
            voxel_grids(
                ev.x, ev.y, ev.t, ev.p, height=height, width=width, num_bins=spec.num_bins,
                t_start_us=window.t_start_us, span_us=sub_us, count=count,
            )
        )  # fmt: skip
    planes = []
    for j in range(count):
        sub = ev.slice_time(window.t_start_us + j * sub_us, window.t_start_us + (j + 1) * sub_us)
        planes.append(
            torch.from_numpy(accumulated_frames(sub.x, sub.y, sub.p, height=height, width=width))
        )
    return torch.stack(planes)


def encode_target(window: Window, input_spec: InputSpec | dict[str, Any]) -> torch.Tensor:
    """The training target for one window, rad/s (float32).

    Returns:
        per_step: (3, T), the layout of the SNN's output.
        window_mean: (S, 3), the mean of the per-millisecond labels in each sub-window.
    """
    spec = as_input_spec(input_spec)
    omega = torch.from_numpy(np.ascontiguousarray(window.omega, dtype=np.float32))
    if spec.output == "per_step":
        return omega.T.contiguous()
    return omega.view(-1, spec.target_ms, 3).mean(dim=1)


# ------------------------------------------------------------------------- event batches


@dataclass(frozen=True)
class EventBatch:
    """The events of a batch of windows as flat lists, to be binned where they are.

    Attributes:
        x, y: int16 pixel coordinates on the model's sensor (already rescaled by the spec).
        t: int32 microseconds since the start of each event's window (0 ≤ t < window_ms·1000).
        p: uint8 polarity, 0 = OFF, 1 = ON.
        counts: int64 (N,) number of events of each window; the lists hold window 0's events,
            then window 1's, and so on.
        width, height: the model's sensor, pixels.
    """

    x: torch.Tensor
    y: torch.Tensor
    t: torch.Tensor
    p: torch.Tensor
    counts: torch.Tensor
    width: int
    height: int

    @property
    def num_windows(self) -> int:
        return int(self.counts.numel())

    def window_index(self) -> torch.Tensor:
        """(n_events,) index of each event's window, on the events' device."""
        windows = torch.arange(self.num_windows, device=self.t.device)
        counts = self.counts.to(self.t.device)
        return windows.repeat_interleave(counts, output_size=int(self.t.numel()))

    def _map(self, fn: Callable[[torch.Tensor], torch.Tensor]) -> EventBatch:
        return EventBatch(
            fn(self.x), fn(self.y), fn(self.t), fn(self.p), self.counts, self.width, self.height
        )

    def to(self, device: torch.device | str, non_blocking: bool = False) -> EventBatch:
        return self._map(lambda a: a.to(device, non_blocking=non_blocking))

    def pin_memory(self) -> EventBatch:
        """Page-locked copies (the DataLoader calls this with ``pin_memory=True``)."""
        return self._map(torch.Tensor.pin_memory)

    @staticmethod
    def concatenate(parts: list[EventBatch]) -> EventBatch:
        first = parts[0]
        return EventBatch(
            *(torch.cat([getattr(b, f) for b in parts]) for f in ("x", "y", "t", "p", "counts")),
            first.width,
            first.height,
        )


def window_events(window: Window, input_spec: InputSpec | dict[str, Any]) -> EventBatch:
    """One window's events, on the model's sensor, as a one-window :class:`EventBatch`."""
    ev = _model_events(window, as_input_spec(input_spec))
    return EventBatch(
        torch.from_numpy(ev.x.astype(np.int16)),
        torch.from_numpy(ev.y.astype(np.int16)),
        torch.from_numpy((ev.t - window.t_start_us).astype(np.int32)),
        torch.from_numpy(ev.p.astype(np.uint8)),
        torch.tensor([len(ev)], dtype=torch.int64),
        ev.width,
        ev.height,
    )


def collate_events(
    samples: list[tuple[EventBatch, torch.Tensor]],
) -> tuple[EventBatch, torch.Tensor]:
    """DataLoader collate of (one-window EventBatch, target) samples: one batch, stacked targets."""
    return EventBatch.concatenate([s[0] for s in samples]), torch.stack([s[1] for s in samples])


def encode_batch(
    batch: EventBatch, input_spec: InputSpec | dict[str, Any], sparse: bool = False
) -> torch.Tensor:
    """The network inputs of a batch, binned on the batch's device.

    Equals ``torch.stack([encode_window(w, spec) for w in windows])`` for the windows the batch
    was made of: spikes (N, 2, H, W, T) (time-major storage; with ``sparse``, a sparse COO
    tensor), voxel (N, S, num_bins, H, W), frames (N, S, 2, H, W).
    """
    spec = as_input_spec(input_spec)
    n, height, width = batch.num_windows, batch.height, batch.width
    window = batch.window_index()
    if spec.representation == "spikes":
        return binning_torch.spike_tensor(
            batch.x, batch.y, batch.t, batch.p, window, num_windows=n, height=height,
            width=width, num_bins=spec.window_ms, sparse=sparse,
        )  # fmt: skip
    # Each target_ms sub-window is a window of its own, with times relative to its start.
    sub_us = spec.target_ms * BIN_US
    sub = torch.div(batch.t, sub_us, rounding_mode="floor")
    per = spec.window_ms // spec.target_ms
    plane = window * per + sub
    if spec.representation == "voxel":
        planes = binning_torch.voxel_grid(
            batch.x, batch.y, batch.t - sub * sub_us, batch.p, plane, num_windows=n * per,
            height=height, width=width, num_bins=spec.num_bins, t_start_us=0, t_end_us=sub_us,
        )  # fmt: skip
    else:
        planes = binning_torch.accumulated_frames(
            batch.x, batch.y, batch.p, plane, num_windows=n * per, height=height, width=width
        )
    return planes.view(n, per, *planes.shape[1:])


def events_on_device(device: torch.device | str, data_path: str, sparse: bool = False) -> bool:
    """Whether training batches travel as event lists (``data_path`` one of DATA_PATHS):
    ``auto`` picks them on CUDA, and for the event-driven CPU engine (``sparse``)."""
    if data_path == "auto":
        return sparse or torch.device(device).type == "cuda"
    return data_path == "events"


def device_batch(
    inputs: torch.Tensor | EventBatch,
    targets: torch.Tensor,
    input_spec: InputSpec | dict[str, Any],
    device: torch.device | str,
    sparse: bool = False,
) -> tuple[torch.Tensor, torch.Tensor]:
    """A collated batch (dense tensors or an :class:`EventBatch`) as model input and target on
    ``device``, shaped by :func:`model_batch`; with ``sparse``, an :class:`EventBatch` of spikes
    becomes a sparse tensor (for the event-driven CPU engine)."""
    inputs = inputs.to(device, non_blocking=True)
    if isinstance(inputs, EventBatch):
        inputs = encode_batch(inputs, input_spec, sparse)
    x, y = model_batch(inputs, targets.to(device, non_blocking=True), input_spec)
    return x, cast(torch.Tensor, y)


# ------------------------------------------------------------------------- training samples


class WindowSource(Protocol):
    """Where training windows come from: ``draw(rng, index) -> Window``."""

    def draw(self, rng: np.random.Generator, index: int) -> Window: ...


@dataclass(frozen=True)
class FileSource:
    """Random windows from sequence files (a uniformly random file, then a random start)."""

    files: tuple[str, ...]
    window_ms: int
    clock: Clock = field(default_factory=Clock)

    @classmethod
    def from_split(
        cls, data_dir: str | Path, split: str, window_ms: int, clock: Clock | None = None
    ) -> FileSource:
        files = tuple(str(p) for p in split_files(data_dir, split))
        return cls(files, window_ms, clock or Clock())

    def _sequence(
        self, rng: np.random.Generator
    ) -> tuple[Recording, Callable[[int, int], EventArray], str]:
        path = self.files[int(rng.integers(len(self.files)))]
        file = sequence_index(path)
        sequence = Recording(EventArray.empty(*file.sensor), file.gyro, file.attrs)
        return sequence, functools.partial(read_hdf5_span, path, index=file), path

    def draw(self, rng: np.random.Generator, index: int) -> Window:
        """The window's events only are read from its file (the same window as
        :func:`random_window` on the whole sequence gives); on an event clock, a window of
        ``window_ms`` steps (:func:`draw_clocked`)."""
        if not self.clock.is_paper:
            return draw_clocked(lambda: self._sequence(rng), self.window_ms, self.clock, rng,
                                index)  # fmt: skip
        sequence, read, path = self._sequence(rng)
        start = random_start(sequence, self.window_ms, rng, path)
        events = read(start, start + self.window_ms * BIN_US)
        return window_at(replace(sequence, events=events), start, self.window_ms, source=path,
                         index=index)  # fmt: skip


@dataclass(frozen=True)
class OnlineSource:
    """Windows from sequences simulated on the fly: sample ``i`` comes from sequence ``i``.

    ``simulate(index) -> Recording`` must be a picklable callable (DataLoader workers call it);
    nothing touches the disk, so the data are unlimited.
    """

    simulate: Callable[[int], Recording]
    window_ms: int
    clock: Clock = field(default_factory=Clock)

    def draw(self, rng: np.random.Generator, index: int) -> Window:
        rec = self.simulate(index)
        if not self.clock.is_paper:
            named = (rec, rec.events.slice_time, f"online:{index}")
            return draw_clocked(lambda: named, self.window_ms, self.clock, rng, index)
        return random_window(rec, self.window_ms, rng, source=f"online:{index}", index=index)


Augment = Callable[[Window, np.random.Generator], Window]


class SampleError(RuntimeError):
    """A training sample could not be made (drawn, augmented or encoded).

    Raised in a DataLoader worker, it reaches the training process with the worker's traceback
    in its message; :func:`sample_error_line` recovers the one-line cause.
    """


def sample_error_line(exc: BaseException) -> str:
    """The one-line cause of a :class:`SampleError`, also as a DataLoader worker re-raised it
    (its message then ends with the worker's traceback, whose last line is the original)."""
    lines = [line for line in str(exc).splitlines() if line.strip()]
    last = lines[-1] if lines else type(exc).__name__
    marker = f"{SampleError.__name__}: "
    return last.split(marker, 1)[1] if marker in last else last


class TrainingSamples(Dataset):
    """Map-style dataset over an endless stream of random training samples.

    With ``events=True`` samples are event lists (collate them with :attr:`collate`).
    Sample ``i`` is a pure function of (seed, i): its randomness comes from
    ``np.random.default_rng([seed, i])``. Training step s of a run with global batch B reads
    samples ``s*B .. s*B + B - 1`` whatever the number of processes or workers, so resumed and
    distributed runs see exactly the data a single uninterrupted run sees.
    """

    def __init__(
        self,
        source: WindowSource,
        input_spec: InputSpec | dict[str, Any],
        *,
        seed: int = 0,
        augment: Augment | None = None,
        length: int = 2**62,
        events: bool = False,
    ) -> None:
        self.source = source
        self.spec = as_input_spec(input_spec)
        self.seed = seed
        self.augment = augment
        self.length = length
        self.events = events

    @property
    def collate(self) -> Callable | None:
        """The DataLoader's collate function (None: PyTorch's default, stacking tensors)."""
        return collate_events if self.events else None

    def __len__(self) -> int:
        return self.length

    def window(self, index: int) -> Window:
        """The (augmented) window of sample ``index``."""
        rng = np.random.default_rng([self.seed, index])
        window = self.source.draw(rng, index)
        return window if self.augment is None else self.augment(window, rng)

    def __getitem__(self, index: int) -> tuple[torch.Tensor | EventBatch, torch.Tensor]:
        """(input, target) of sample ``index``: the encoded input, or with ``events`` the
        window's event lists (encoded later, on the device, by :func:`encode_batch`)."""
        try:
            window = self.window(index)
            encode = window_events if self.events else encode_window
            return encode(window, self.spec), encode_target(window, self.spec)
        except Exception as exc:  # whatever a reader, augmentation or encoder raises
            cause = " ".join(f"{type(exc).__name__}: {exc}".split())
            raise SampleError(f"training sample {index} (seed {self.seed}): {cause}") from exc


def model_batch(
    inputs: torch.Tensor, targets: torch.Tensor | None, input_spec: InputSpec | dict[str, Any]
) -> tuple[torch.Tensor, torch.Tensor | None]:
    """Shape a stacked batch for the model: ANN sub-windows become batch entries.

    spikes: (N, 2, H, W, T) and (N, 3, T) unchanged; voxel/frames: (N, S, C, H, W) ->
    (N*S, C, H, W) and (N, S, 3) -> (N*S, 3).
    """
    if as_input_spec(input_spec).output == "per_step":
        return inputs, targets
    flat = inputs.flatten(0, 1)
    return flat, None if targets is None else targets.flatten(0, 1)
