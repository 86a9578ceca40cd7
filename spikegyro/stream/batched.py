"""Batched prediction on a torch device: many segments of a recording in one forward pass.

The event-driven stream (:mod:`spikegyro.stream.stateful`) is exact and runs one 1 ms step
after another on the CPU. For throughput on a GPU this path cuts the recording into segments of
``segment_ms``; segment j predicts the bins ``[j L, (j + 1) L)`` (ms after the start) from the
spike tensor of ``[j L − W, (j + 1) L)``, i.e. ``context_ms`` = W ms of warm-up that overlap the
previous segment, bins a batch of segments on the device
(:func:`spikegyro.events.binning_torch.spike_tensor`), runs the batch forward ``model(x)`` and
keeps each segment's last L outputs. Segment 0's context lies before the first event: empty
bins, and a network at rest stays at rest, so its outputs are the stream's.

Later segments are approximations: an SRM neuron's state depends on its whole past (the
refractory recursion feeds back its own spikes), and the network is restarted from rest W ms
before each segment. The psp kernels fade within tens of ms, so with enough context the
outputs agree with the stream's up to spikes that flip near threshold;
``tests/test_stream_batched.py`` and ``bench/batched_predict.py`` measure how far.

float32, no autocast (spike thresholds are sensitive to rounding), ``torch.inference_mode``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from spikegyro.errors import InputError
from spikegyro.events import binning_torch
from spikegyro.events.calib import PinholeCamera
from spikegyro.events.core import EventArray
from spikegyro.events.windows import BIN_US
from spikegyro.models.registry import load_checkpoint
from spikegyro.stream.model import load_streaming_spec
from spikegyro.stream.predict import PredictorFactory
from spikegyro.stream.stateful import SNNSpec

__all__ = [
    "BatchedPredictor",
    "SegmentConfig",
    "batched_predictor",
    "deviation",
    "model_predictor",
    "resolve_device",
]

_MEMORY_SHARE = 0.5
"""Share of the device's free memory the activations of one batch may take."""
_ACTIVATION_COPIES = 4
"""Float32 tensors per neuron and step alive at once in a forward pass (input, psp, conv
output, spikes): the per-segment memory estimate."""
_MAX_AUTO_BATCH = 64


@dataclass(frozen=True)
class SegmentConfig:
    """How the recording is cut.

    Attributes:
        segment_ms: outputs kept per segment, ms (L).
        context_ms: warm-up steps before each segment whose outputs are dropped, ms (W).
        batch: segments per forward pass; None chooses from the device's free memory.
    """

    segment_ms: int = 400
    context_ms: int = 100
    batch: int | None = None

    def __post_init__(self) -> None:
        if self.segment_ms < 1 or self.context_ms < 0 or (self.batch is not None
                                                            and self.batch < 1):  # fmt: skip
            raise InputError(
                f"--segment-ms {self.segment_ms}, --context-ms {self.context_ms}, --batch "
                f"{self.batch}: need a segment of at least 1 ms, context >= 0 and batch >= 1."
            )


def resolve_device(name: str) -> torch.device:
    """The torch device called ``name`` (``cpu``, ``cuda``, ``cuda:1``); InputError when it
    does not exist here."""
    try:
        device = torch.device(name)
    except RuntimeError:
        raise InputError(
            f"--device {name}: not a device; use 'stream', 'cpu', 'cuda' or 'cuda:N'."
        ) from None
    if device.type == "cuda":
        count = torch.cuda.device_count() if torch.cuda.is_available() else 0
        if count == 0:
            raise InputError(
                f"--device {name}: this torch ({torch.__version__}) sees no CUDA GPU; use "
                "--device stream (default) or cpu."
            )
        if (device.index or 0) >= count:
            raise InputError(f"--device {name}: there are only {count} CUDA devices.")
    elif device.type != "cpu":
        raise InputError(f"--device {name}: only 'stream', 'cpu' and 'cuda[:N]' are supported.")
    return device


def segment_bytes(layer_neurons: list[int], steps: int) -> int:
    """Estimated peak activation memory of one segment of ``steps`` ms, bytes.

    Args:
        layer_neurons: neurons of the input and of every spiking layer (C·H·W each).
    """
    return _ACTIVATION_COPIES * 4 * steps * sum(layer_neurons)


def auto_batch(device: torch.device, per_segment: int) -> int:
    """Segments per forward pass that fit in half the free memory of ``device`` (1 … 64)."""
    if device.type == "cuda":
        free = torch.cuda.mem_get_info(device)[0]
    else:
        free = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    return int(np.clip(int(free * _MEMORY_SHARE) // max(per_segment, 1), 1, _MAX_AUTO_BATCH))


class BatchedPredictor:
    """A :class:`spikegyro.stream.predict.Predictor` that runs segments in batches on a device.

    Holds the events of the segments not yet run plus the context of the next one (at most
    ``batch`` segments and W ms of events), so memory stays flat in the recording's length.

    Args:
        model: the network, (N, 2, H, W, T) spikes -> ω (N, 3, T) rad/s, on ``device``.
        camera: the model's input camera (height, width of the spike tensor).
        t0_us: start of the first bin, µs.
        config: segment and context length, batch.
        batch: segments per forward pass (resolved, not None).
    """

    def __init__(
        self,
        model: nn.Module,
        camera: PinholeCamera,
        t0_us: int,
        device: torch.device,
        config: SegmentConfig,
        batch: int,
    ) -> None:
        self.model, self.device, self.config, self.batch = model, device, config, batch
        self.height, self.width = camera.height, camera.width
        self.t0_us = int(t0_us)
        self.steps = 0
        self.label = (
            f"batched torch on {device} (approximate; segments of {config.segment_ms} ms "
            f"after {config.context_ms} ms of context, {batch} per batch)"
        )
        self._pending: list[EventArray] = []

    def push(self, events: EventArray) -> tuple[np.ndarray, np.ndarray]:
        """Add events; runs and returns the next ``batch`` segments once they are complete."""
        self._pending.append(events)  # even empty: finish() then has the sensor's size
        if not len(events):
            return _empty()
        complete = int(events.t[-1] - self.t0_us) // BIN_US  # bins fully seen
        length = self.config.segment_ms
        ready = complete // length - self.steps // length
        if ready < self.batch:
            return _empty()
        return self._run(self.steps + ready // self.batch * self.batch * length)

    def finish(self, t_end_us: int) -> tuple[np.ndarray, np.ndarray]:
        """Run every remaining bin up to the one holding ``t_end_us - 1``."""
        return self._run(-(-(int(t_end_us) - self.t0_us) // BIN_US))

    def _run(self, n_total: int) -> tuple[np.ndarray, np.ndarray]:
        """Predict bins ``steps … n_total − 1``, ``batch`` segments per forward pass."""
        if n_total <= self.steps:
            return _empty()
        ev = EventArray.concatenate(self._pending)
        length, context = self.config.segment_ms, self.config.context_ms
        starts = np.arange(self.steps, n_total, length)
        omega = []
        for i in range(0, len(starts), self.batch):
            omega.append(self._forward(ev, starts[i : i + self.batch]))
        omega = np.concatenate(omega)[: n_total - self.steps]
        t_us = self.t0_us + (self.steps + 1 + np.arange(len(omega), dtype=np.int64)) * BIN_US
        self.steps = n_total
        keep = int(np.searchsorted(ev.t, self.t0_us + (n_total - context) * BIN_US))
        self._pending = [ev[keep:]]
        return t_us, omega

    def _forward(self, ev: EventArray, starts: np.ndarray) -> np.ndarray:
        """ω (len(starts) · L, 3) of the segments starting at bins ``starts``."""
        length, context = self.config.segment_ms, self.config.context_ms
        begin = self.t0_us + (starts - context) * BIN_US  # window starts, µs
        lo = np.searchsorted(ev.t, begin)
        hi = np.searchsorted(ev.t, begin + (context + length) * BIN_US)
        pick = np.concatenate([np.arange(a, b) for a, b in zip(lo, hi, strict=True)])
        window = np.repeat(np.arange(len(starts), dtype=np.int64), hi - lo)
        # times relative to each window's start fit in int32: one small transfer per batch
        rel = (ev.t[pick] - begin[window]).astype(np.int32)
        dev = self.device

        def put(a: np.ndarray) -> torch.Tensor:
            return torch.from_numpy(np.ascontiguousarray(a)).to(dev, non_blocking=True)

        with torch.inference_mode():
            x = binning_torch.spike_tensor(
                put(ev.x[pick]), put(ev.y[pick]), put(rel), put(ev.p[pick]), put(window),
                num_windows=len(starts), height=self.height, width=self.width,
                num_bins=context + length,
            )  # fmt: skip
            # the parameters' dtype: float32 from the CLI, float64 for exact comparisons
            x = x.to(next(self.model.parameters()).dtype)
            omega = self.model(x)[:, :, context:]  # (n, 3, L)
            return omega.transpose(1, 2).reshape(-1, 3).double().cpu().numpy()


def deviation(got: np.ndarray, exact: np.ndarray, skip: int) -> tuple[float, float]:
    """How far batched ω is from the stream's: (median, max) over steps ``skip`` … of
    |Δω| / median |ω| (Euclidean norms of (K, 3) rad/s; unitless)."""
    scale = np.median(np.linalg.norm(exact[skip:], axis=1))
    err = np.linalg.norm(got[skip:] - exact[skip:], axis=1) / scale
    return float(np.median(err)), float(err.max())


def _empty() -> tuple[np.ndarray, np.ndarray]:
    return np.zeros(0, np.int64), np.zeros((0, 3))


def batched_predictor(
    checkpoint: str | os.PathLike, device: str, config: SegmentConfig = SegmentConfig()
) -> tuple[PredictorFactory, dict[str, Any]]:
    """Load a checkpoint's network onto ``device``, like
    :func:`spikegyro.stream.model.load_streaming_model`: returns (the factory
    :func:`~spikegyro.stream.predict.predict_stream` takes as its engine, metadata). Raises
    InputError for a missing device or a model that does not predict every step."""
    dev = resolve_device(device)
    spec, meta = load_streaming_spec(Path(checkpoint))  # checks it is a per-step SNN
    model, _ = load_checkpoint(checkpoint)
    return model_predictor(model.to(dev, torch.float32), dev, config, spec), meta


def model_predictor(
    model: nn.Module, device: torch.device, config: SegmentConfig, spec: SNNSpec
) -> PredictorFactory:
    """The factory of :class:`BatchedPredictor` for a network already on ``device``; ``spec``
    (:func:`spikegyro.stream.model.spec_from_model`) gives its layer sizes for the memory
    estimate of the automatic batch size."""
    batch = config.batch
    if batch is None:
        neurons = [int(np.prod(spec.input_shape))]
        neurons += [c * h * w for c, h, w in spec.layer_shapes()]
        steps = config.segment_ms + config.context_ms
        batch = auto_batch(device, segment_bytes(neurons, steps))
    model.eval()

    def make(camera: PinholeCamera, t0_us: int) -> BatchedPredictor:
        return BatchedPredictor(model, camera, t0_us, device, config, batch)

    return make
