"""Real recordings as unlabeled training windows: loading, checks, sampling, held-out validation.

Each recording is read whole into memory (real training sets are seconds long) with its
calibration. The last ``holdout`` share of each recording's span is held out: its windows tile
the validation set, scored by contrast gain (:mod:`spikegyro.train.selfsup`), never trained on.

Real windows are not augmented: a flip mirrors the image but not the lens distortion the loss
warps with, and a time-reversed real stream differs from any real one (ON and OFF events have
different thresholds and latencies on a real sensor).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import numpy as np
import torch
from rich.progress import Progress

from spikegyro.cmax.problem import Intrinsics
from spikegyro.errors import InputError
from spikegyro.events.calib import Calibration, load_calibration, resolve_calibration
from spikegyro.events.core import EventArray
from spikegyro.events.io import read_recording
from spikegyro.stream.predict import focal_gain
from spikegyro.train.data import (
    BIN_US,
    EventBatch,
    InputSpec,
    Window,
    clocked_window,
    encode_window,
    window_events,
)
from spikegyro.train.infer import predict_windows
from spikegyro.train.selfsup import (
    ContrastLossConfig,
    SubWindow,
    TeacherSeries,
    gain_of_prediction,
    scored_sub_window,
    teacher_series,
)

GRID_US = 5 * BIN_US
"""Real windows start on a 5 ms grid, so that the teacher's estimates are reused across steps."""

MIN_EVENTS_PER_S = 2000
"""A recording with fewer events per second than this has too little to learn from."""


@dataclass(frozen=True)
class RealRecording:
    """One real recording in memory: its events, camera, the ranges of window starts to train
    and to validate on (µs, inclusive), and contrast maximization's estimates over it."""

    name: str
    events: EventArray
    camera: Intrinsics
    train_span: tuple[int, int]
    val_span: tuple[int, int]
    teacher: TeacherSeries


def parse_camera(spec: str) -> Calibration:
    """A ``--real-calib`` value: a calibration file, or ``fx,fy,cx,cy`` in pixels."""
    if not Path(spec).exists():
        try:
            fx, fy, cx, cy = (float(v) for v in spec.split(","))
        except ValueError:
            pass
        else:
            camera, _ = resolve_calibration(spec, None, (fx, fy, cx, cy))
            return cast(Calibration, camera)
    if not Path(spec).is_file():
        raise InputError(
            f"--real-calib {spec}: neither a calibration file nor 'fx,fy,cx,cy' in pixels."
        )
    return load_calibration(spec)


def _cameras(paths: list[str], calibs: list[str]) -> list[Intrinsics]:
    """One camera per recording: its own ``--real-calib`` (one for all, or one each in order),
    else an Event Camera Dataset folder's calib.txt."""
    if calibs and len(calibs) not in (1, len(paths)):
        raise InputError(
            f"--real-calib given {len(calibs)} times for {len(paths)} recordings: give one for "
            "all, or one per --real in the same order."
        )
    cameras = []
    for i, path in enumerate(paths):
        spec = calibs[i if len(calibs) > 1 else 0] if calibs else None
        camera = parse_camera(spec) if spec else resolve_calibration(path)[0]
        if camera is None:
            raise InputError(
                f"{path}: no calibration; the contrast loss warps events through the camera, so "
                "give --real-calib FILE or --real-calib fx,fy,cx,cy (pixels)."
            )
        cameras.append(camera)
    return cameras


def load_recordings(
    paths: list[str],
    calibs: list[str],
    window_ms: int,
    holdout: float,
    loss: ContrastLossConfig,
    progress: bool = True,
    span_s: tuple[float, float | None] = (0.0, None),
) -> list[RealRecording]:
    """Read and check the real recordings of a run (see the module docstring), and run
    contrast maximization over each (the teacher; about 25 ms of CPU per 5 ms of recording).
    ``span_s``: the part of each recording used, seconds after its first event.

    Raises :class:`InputError` for an unreadable file, a missing calibration, too few events or
    a recording too short for a training and a validation window, before any teacher work.
    """
    if not 0.0 < holdout < 1.0:
        raise InputError(f"--real-holdout {holdout}: give a share between 0 and 1 (e.g. 0.2).")
    cameras = _cameras(paths, calibs)
    parts = []
    for path, camera in zip(paths, cameras, strict=True):
        try:
            events = _cropped(read_recording(path).events, span_s)
        except (OSError, ValueError) as exc:
            raise InputError(f"{path}: cannot read it as an event recording ({exc}).") from None
        parts.append((path, events, camera, _spans(path, events, window_ms, holdout)))
    with Progress(transient=True, disable=not progress) as bar:
        recordings = []
        for path, events, camera, (train, val) in parts:
            count = (int(events.t[-1]) - int(events.t[0])) // GRID_US
            task = bar.add_task(f"contrast maximization over {Path(path).name}", total=count)
            teacher = teacher_series(
                events, camera, loss, GRID_US, progress=lambda k, t=task: bar.update(t, completed=k)
            )
            recordings.append(RealRecording(str(path), events, camera, train, val, teacher))
    return recordings


def _cropped(events: EventArray, span_s: tuple[float, float | None]) -> EventArray:
    """The events from ``span_s[0]`` to ``span_s[1]`` seconds after the first one."""
    if not len(events) or span_s == (0.0, None):
        return events
    first = int(events.t[0])
    end = events.t[-1] + 1 if span_s[1] is None else first + round(span_s[1] * 1e6)
    return events.slice_time(first + round(span_s[0] * 1e6), int(end))


def _spans(
    path: str, events: EventArray, window_ms: int, holdout: float
) -> tuple[tuple[int, int], tuple[int, int]]:
    """Check a recording; the ranges of window starts (µs, on the teacher's grid) before and
    after its held-out split."""
    if len(events) < 2:
        raise InputError(f"{path}: {len(events)} events; a real recording needs many thousands.")
    t0, t1 = int(events.t[0]), int(events.t[-1])
    seconds = (t1 - t0) * 1e-6
    window_us = window_ms * BIN_US
    if len(events) < MIN_EVENTS_PER_S * seconds:
        raise InputError(
            f"{path}: {len(events)} events in {seconds:.2f} s, fewer than "
            f"{MIN_EVENTS_PER_S} per second: too few to learn from."
        )
    split = t0 + round((t1 - t0) * (1.0 - holdout) / GRID_US) * GRID_US
    if split - t0 < window_us or t1 - split < window_us:
        raise InputError(
            f"{path}: {seconds * 1000:.0f} ms long; with --real-holdout {holdout} it needs at "
            f"least {window_ms} ms on each side of the split ({2 * window_ms / 1000:.2f} s in all)."
        )
    return (t0, split - window_us), (split, t1 - window_us)


def unlabeled_window(events: EventArray, t_start_us: int, window_ms: int, source: str) -> Window:
    """A window with no ground truth (NaN), for the model's data path."""
    nan = np.full((window_ms, 3), math.nan, dtype=np.float32)
    end = t_start_us + window_ms * BIN_US
    return Window(events.slice_time(t_start_us, end), t_start_us, nan, nan[0], source)


class RealWindows:
    """Unlabeled real windows: random ones for training steps, fixed ones for validation, each
    with its scored sub-windows."""

    def __init__(
        self,
        recordings: list[RealRecording],
        spec: InputSpec,
        loss: ContrastLossConfig,
        seed: int = 0,
    ) -> None:
        self.recordings = recordings
        self.spec = spec
        self.loss = loss
        self.seed = seed

    def _scored(
        self, index: int, start: int, known_us: int
    ) -> tuple[Window, list[SubWindow]] | None:
        """The window from ``start`` (µs) and its scored sub-windows, each ending where its step
        ends; on the event clock None where the steps run past ``known_us``."""
        rec, steps, clock = self.recordings[index], self.spec.window_ms, self.spec.step_clock
        if clock.is_paper:
            window = unlabeled_window(rec.events, start, steps, rec.name)
            ends = start + BIN_US * np.arange(1, steps + 1)
        else:
            found = clocked_window(rec.events.slice_time, None, start, known_us, steps, clock,
                                   source=rec.name)  # fmt: skip
            if found is None:
                return None
            window, ends = found, start + np.cumsum(found.step_us)
        # the sensor's own pixels: tilt and pan read through the focal length (--pixels sensor)
        gain = focal_gain(self.spec.as_dict(), rec.camera)
        subs = []
        for step in self.loss.steps(steps):
            sub = scored_sub_window(rec.events, int(ends[step]), step, rec.camera, rec.teacher,
                                    self.loss, window.rates[step] * gain)  # fmt: skip
            if sub is not None:
                subs.append(sub)
        return window, subs

    def draw(self, step: int, count: int) -> list[tuple[Window, list[SubWindow]]]:
        """``count`` training windows of optimizer step ``step`` (a pure function of the seed
        and the step): recordings drawn in proportion to their training span (on the event
        clock, a window whose steps would reach the held-out part is drawn again)."""
        rng = np.random.default_rng([self.seed, step, 7])
        spans = np.array([r.train_span[1] - r.train_span[0] + 1 for r in self.recordings], float)
        out = []
        for _ in range(20 * count):
            if len(out) == count:
                return out
            index = int(rng.choice(len(spans), p=spans / spans.sum()))
            lo, hi = self.recordings[index].train_span
            start = lo + int(rng.integers(0, (hi - lo) // GRID_US + 1)) * GRID_US
            scored = self._scored(index, start, hi + self.spec.window_ms * BIN_US)
            if scored is not None:
                out.append(scored)
        raise InputError(
            f"real windows of {self.spec.window_ms} steps ({self.spec.step_clock.label}) run "
            "past the recordings' training spans; use fewer steps per window."
        )

    def validation(self) -> list[tuple[Window, list[SubWindow]]]:
        """The held-out windows, tiling each recording's held-out span (from each start on
        the paper's clock; on the event clock those whose steps end in the recording)."""
        out = []
        step_us = self.spec.window_ms * BIN_US
        for index, rec in enumerate(self.recordings):
            lo, hi = rec.val_span
            end = int(rec.events.t[-1])
            scored = [self._scored(index, start, end) for start in range(lo, hi + 1, step_us)]
            out += [s for s in scored if s is not None]
        if not out:
            raise InputError(
                f"the held-out part of the real recordings holds no window of "
                f"{self.spec.window_ms} steps ({self.spec.step_clock.label}); give longer "
                "recordings (slow motion makes the event clock's steps long)."
            )
        return out


def model_inputs(windows: list[Window], spec: InputSpec, events: bool) -> Any:
    """Windows in the form the run's data path carries: one :class:`EventBatch` (``events``)
    or a stacked dense tensor."""
    if events:
        return EventBatch.concatenate([window_events(w, spec) for w in windows])
    return torch.stack([encode_window(w, spec) for w in windows])


class RealValidation:
    """The held-out real windows of a run, scored once, and how the model does on them."""

    def __init__(self, source: RealWindows) -> None:
        self.source = source
        self.scored = source.validation()

    @property
    def windows(self) -> list[Window]:
        """The held-out windows."""
        return [w for w, _ in self.scored]

    def score(self, model: torch.nn.Module) -> dict[str, float]:
        """The mean contrast gain of the model's estimates on the windows, and of contrast
        maximization's (the ceiling one rotation per sub-window reaches); the model's training
        mode is kept."""
        was_training = model.training
        prediction = predict_windows(model, self.source.spec, self.windows, batch_size=8)
        model.train(was_training)
        sigma = self.source.loss.sigma_px
        gains = [
            gain_of_prediction(p, subs, sigma)
            for p, (_, subs) in zip(prediction, self.scored, strict=True)
        ]
        ceiling = [s.teacher_gain for _, subs in self.scored for s in subs]
        return {
            "val_real_gain": float(np.nanmean(gains)) if gains else math.nan,
            "val_real_gain_cmax": float(np.mean(ceiling)) if ceiling else math.nan,
        }
