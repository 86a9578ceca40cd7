"""Batched prediction over event windows, for validation, evaluation and the demo."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from torch import nn

from spikegyro.events.windows import series_per_window
from spikegyro.train.data import (
    EventBatch,
    InputSpec,
    Window,
    as_input_spec,
    encode_batch,
    encode_window,
    model_batch,
    window_events,
)


def spec_of(payload_or_input_spec: dict[str, Any] | InputSpec) -> InputSpec:
    """The input spec from a checkpoint payload (``payload["input"]``) or a spec itself."""
    if isinstance(payload_or_input_spec, dict) and "input" in payload_or_input_spec:
        return as_input_spec(payload_or_input_spec["input"])
    return as_input_spec(payload_or_input_spec)


def per_millisecond(outputs: torch.Tensor, spec: InputSpec, num_windows: int) -> torch.Tensor:
    """Model outputs as ω per ms, (n, T, 3) rad/s.

    An SNN's (n, 3, T) output is transposed; an ANN's (n*S, 3) window means are held constant
    over their ``target_ms`` sub-window, so both can be scored against per-ms ground truth.
    """
    if spec.output == "per_step":
        return outputs.transpose(1, 2)
    means = outputs.view(num_windows, -1, 3)
    return means.repeat_interleave(spec.target_ms, dim=1)


@torch.no_grad()
def predict_windows(
    model: nn.Module,
    payload_or_input_spec: dict[str, Any] | InputSpec,
    windows: list[Window],
    batch_size: int = 8,
    *,
    device: str | torch.device | None = None,
    progress: Any = None,
) -> np.ndarray:
    """Angular velocity predicted for each window at each millisecond.

    Args:
        model: a model built for ``input_spec`` (put in eval mode here).
        payload_or_input_spec: a checkpoint dict, its ``input`` dict or an :class:`InputSpec`.
        windows: windows of ``input_spec.window_ms`` ms.
        batch_size: windows per forward pass.
        device: where to run; default: the model's device.
        progress: optional callable ``progress(done_windows)`` (e.g. a rich progress update).

    Returns:
        (n, T, 3) float32 array, rad/s; entry k is the estimate at the end of bin k.
    """
    spec = spec_of(payload_or_input_spec)
    model.eval()
    if device is None:
        device = next(iter(model.parameters())).device

    # The event-driven CPU engine reads the spikes as a sparse tensor, never a dense one.
    engine = getattr(model, "event_engine", None) is not None
    sparse = engine and spec.representation == "spikes" and torch.device(device).type == "cpu"

    def forward(chunk: list[Window]) -> np.ndarray:
        if sparse:
            events = EventBatch.concatenate([window_events(w, spec) for w in chunk])
            inputs = encode_batch(events, spec, sparse=True)
        else:
            inputs = torch.stack([encode_window(w, spec) for w in chunk])
        x, _ = model_batch(inputs, None, spec)
        y = model(x.to(device)).float().cpu()
        return per_millisecond(y, spec, len(chunk)).numpy()

    return series_per_window(forward, windows, spec.window_ms, batch_size, progress, np.float32)
