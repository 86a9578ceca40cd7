"""The training step, and how fast a run moves samples against how fast the bare step could.

A run is data-bound when its samples/s fall short of the *bare step*: the same step (forward,
backward, optimizer update) repeated on one batch that is already on the device, so that no data
loading, host-device copy or input binning is involved. :class:`RunClock` times the run itself,
:func:`bare_step_rate` the bare step, in the same process and on the same device, so the ratio
of the two says how much of the device the data path leaves idle.
"""

from __future__ import annotations

import contextlib
import copy
import math
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import torch
from torch import nn

from spikegyro.train.loss import angular_velocity_loss


def train_step(
    net: nn.Module,
    optimizer: torch.optim.Optimizer,
    x: torch.Tensor,
    y: torch.Tensor,
    loss_start_step: int,
    grad_clip: float = 0.0,
    amp: bool = False,
    extra_loss: Callable[[torch.Tensor], torch.Tensor] | None = None,
) -> torch.Tensor:
    """One optimizer step on a batch; returns the (detached) loss.

    ``grad_clip`` > 0 clips the gradient norm of ``net``'s parameters first. ``amp`` runs the
    forward pass under bfloat16 autocast; the loss is taken in float32. The batch's first
    ``len(y)`` outputs are scored against ``y`` (rad/s); ``extra_loss``, when given, scores the
    outputs after them (unlabeled windows) and is added.
    """
    with torch.autocast(x.device.type, dtype=torch.bfloat16, enabled=amp):
        out = net(x).float()
    n = len(y)
    loss = angular_velocity_loss(out[:n], y, loss_start_step) if n else out.new_zeros(())
    if extra_loss is not None:
        loss = loss + extra_loss(out[n:])
    optimizer.zero_grad(set_to_none=True)
    loss.backward()
    if grad_clip > 0:
        nn.utils.clip_grad_norm_(net.parameters(), grad_clip)
    optimizer.step()
    return loss.detach()


def cpu_has_bfloat16() -> bool:
    """Whether this CPU computes in bfloat16 natively (AVX-512 BF16 or AMX, as oneDNN finds):
    on such a CPU bfloat16 autocast measured 1.9-2.8x faster than float32 for the ANNs' steps, on
    one without it 7-10x slower."""
    probe = getattr(torch.ops.mkldnn, "_is_mkldnn_bf16_supported", None)
    return bool(probe is not None and probe())


def resolve_amp(amp: str, representation: str, device: torch.device) -> str:
    """The precision a run trains in, "bf16" or "off", for its ``--amp`` (``auto``: bfloat16
    autocast for an ANN, whose ``representation`` is not spikes, on a CPU with bfloat16
    instructions, where it measured 1.9-2.8x faster; float32 on other CPUs, where it is several
    times slower, and on GPUs, where it gained ResNet-50 1.14x and cost ANN-6 0.7-0.85x)."""
    if amp != "auto":
        return amp
    ann = representation != "spikes"
    return "bf16" if ann and device.type == "cpu" and cpu_has_bfloat16() else "off"


def synchronize(device: torch.device) -> None:
    """Wait for the device's queued work (CUDA runs asynchronously), so wall time is true."""
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def timed_steps(
    step: Callable[[], object], device: torch.device, *, warmup: int, repeats: int
) -> tuple[list[float], float | None]:
    """Seconds of each of ``repeats`` calls of ``step``, each timed alone with the device
    synchronized, after ``warmup`` untimed calls; and the peak device memory of the timed calls
    (GiB; None off CUDA)."""
    for _ in range(warmup):
        step()
    synchronize(device)
    cuda = device.type == "cuda"
    if cuda:
        torch.cuda.reset_peak_memory_stats(device)
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        step()
        synchronize(device)
        times.append(time.perf_counter() - start)
    return times, torch.cuda.max_memory_allocated(device) / 2**30 if cuda else None


@dataclass(frozen=True)
class BareStep:
    """Speed of the bare training step: ms per step and windows per second."""

    ms_per_step: float
    samples_per_s: float
    steps: int


def bare_step_rate(
    model: nn.Module,
    x: torch.Tensor,
    y: torch.Tensor,
    *,
    windows: int,
    loss_start_step: int,
    lr: float,
    grad_clip: float = 0.0,
    steps: int = 10,
    amp: bool = False,
) -> BareStep:
    """Time ``steps`` training steps of a copy of ``model`` (Adam, fresh state) on one batch.

    The model itself is not changed. One untimed warm-up step comes first (kernel selection,
    allocator growth).

    Args:
        x, y: a model-ready batch and its target, on the model's device.
        windows: windows in the batch (an ANN batch holds several sub-windows per window).
    """
    net = copy.deepcopy(model).train()
    optimizer = torch.optim.Adam(net.parameters(), lr=lr)
    device = x.device
    train_step(net, optimizer, x, y, loss_start_step, grad_clip, amp)
    synchronize(device)
    start = time.perf_counter()
    for _ in range(steps):
        train_step(net, optimizer, x, y, loss_start_step, grad_clip, amp)
    synchronize(device)
    seconds = (time.perf_counter() - start) / steps
    return BareStep(1000.0 * seconds, windows / seconds, steps)


class RunClock:
    """Samples/s of a training loop in steady state.

    Counts from the end of the first step (which pays for worker start-up and warm-up) to the end
    of the last one, without the time spent inside :meth:`paused` (validation, checkpoints).
    The loop synchronizes with the device every step (it reads the loss), so wall time is true.
    """

    def __init__(self, samples_per_step: int) -> None:
        self.samples_per_step = samples_per_step
        self.steps = 0
        self.busy_s = 0.0
        self._last: float | None = None
        self._paused_s = 0.0

    def step(self) -> None:
        """Mark the end of a training step."""
        now = time.perf_counter()
        if self._last is not None:
            self.steps += 1
            self.busy_s += now - self._last - self._paused_s
        self._last, self._paused_s = now, 0.0

    @contextlib.contextmanager
    def paused(self) -> Iterator[None]:
        """Leave the enclosed time out of the count."""
        start = time.perf_counter()
        try:
            yield
        finally:
            self._paused_s += time.perf_counter() - start

    @property
    def samples_per_s(self) -> float:
        """Windows per second over the counted steps (nan before the second step)."""
        if not self.steps or self.busy_s <= 0:
            return math.nan
        return self.steps * self.samples_per_step / self.busy_s
