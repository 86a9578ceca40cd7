"""Training configuration: one dataclass, named presets, and command-line overrides.

``paper`` reproduces the paper's schedule (240x180, Adam 1e-4, batch 16, 240,000 iterations; a
GPU job). ``cpu`` is what ``spikegyro demo`` trains on a laptop: events rescaled to 120x90, 40 ms
training windows, small batches and a few hundred iterations under a time budget (see the
``cpu`` entry below for the measurements behind it).
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, fields
from typing import Any

from spikegyro.checks import check_device
from spikegyro.errors import InputError
from spikegyro.events.clock import Clock
from spikegyro.models.snn6 import SNN6_LAYERS
from spikegyro.snn.functional import TAU_RHO
from spikegyro.train.data import DATA_PATHS

AMP_MODES = ("auto", "off", "bf16")
COMPUTE_MODES = ("auto", "sparse", "dense")
SPARSE_DEFAULT_CUT = 0.2
"""Surrogate cut of the sparse engine by default: ρ kept where |u − θ| <= 0.48θ (gradients with
a cosine similarity of 0.996 or more per tensor to the unbounded surrogate's on SNN-6, and a
quarter less work than the cut 0.05, |u − θ| <= 0.9θ)."""
SPARSE_MIN_CUT = math.exp(-1.0 / TAU_RHO)
"""Below this cut the surrogate's support reaches u = 0, where every neuron at rest sits."""
MODEL_INPUTS = {"snn6": "spikes", "snn6-grid": "spikes", "ann6": "voxel", "resnet50": "voxel"}


@dataclass(frozen=True)
class TrainConfig:
    """Everything a training run depends on; saved as ``config.json`` in the run directory.

    Attributes:
        preset: name of the preset these values started from.
        data: dataset directory (``DIR/{train,val,test}/*.h5``); optional with ``online``.
        online: simulate fresh training sequences in the DataLoader workers instead of reading
            ``data/train`` (unlimited data, nothing written to disk).
        out: run directory (config.json, log.csv, last.pt, best.pt, resume.pt, loss.png).
        model: registry name: snn6, ann6 or resnet50.
        input: representation: spikes (SNN), voxel or frames (ANNs); "" = the model's default.
        model_kwargs: extra constructor arguments of the model.
        init: checkpoint whose weights start the training (fine-tuning); "" = random init.
        freeze: the SNN's first this many spiking layers keep their (``init``) weights; only the
            later layers and the readout learn (0 = all learn).
        learn_tau: the SNN also learns the time constants τs and τr of every spiking layer and
            τs of the readout (``SNN6(learn_tau=True)``; frozen layers keep theirs).
        sensor: (width, height) of the dataset's events, pixels.
        scale: factor on event coordinates before binning (0.5: 240x180 -> 120x90).
        window_ms: window length, ms, of validation windows and of the checkpoint's input spec.
        num_bins: voxel-grid bins per ANN window; target_ms: ANN window, ms.
        loss_start_step: first step (ms) counted by the validation metrics (and the loss).
        train_window_ms, train_loss_start_step: the same for training windows (0 = as above,
            the start scaled with the window).
            Training windows start at random whole milliseconds. The SNN is time-invariant, so
            shorter training windows (e.g. 40 ms scored from step 20) see more windows per
            second of compute and still apply to 100 ms windows.
        batch_size: windows per optimizer step, summed over all processes.
        lr: Adam learning rate; lr_schedule: "constant" or "cosine" (to lr_min_factor * lr);
        warmup_steps: linear warm-up from 0; grad_clip: max gradient norm (0 = off).
        iterations: optimizer steps; max_minutes: stop gracefully after this much wall time
            (0 = no limit), validating and checkpointing first.
        patience: stop once this many validations in a row have not improved on the best
            (``best.pt``'s score), counted in steps of ``val_every`` (0 = off).
        hflip, vflip, time_reverse: probability of each augmentation.
        event_keep_min: event-drop augmentation: each training window keeps a share
            U(event_keep_min, 1) of its events (1 = off, the paper).
        noise_events_hz: each training window gains uniform background events at a per-pixel
            rate U(0, noise_events_hz) Hz (0 = off, the paper).
        centre_crop: probability that a training window keeps only the events of a centred box
            (an aperture; 0 = off, the paper). Teaches roll from events near the optical axis.
        seed: seeds the model initialisation and every training sample.
        val_every: validate and checkpoint every this many steps (and at the end).
        val_windows: validate on at most this many fixed windows (0 = all).
        val_sequences: sequences simulated for validation in online mode without ``data``.
        log_every: steps per CSV log row.
        num_workers: DataLoader worker processes per training process (at most the cores
            this process may run on).
        threads: torch intra-op threads (0 = torch's default).
        device: "auto", "cpu", "cuda" or "cuda:K".
        data_path: how training batches reach the device: "events" (event lists, binned on the
            device; for the event-driven engine into a sparse tensor, never a dense one), "dense"
            (input tensors encoded in the DataLoader workers) or "auto" (events on CUDA and with
            ``compute`` sparse, dense otherwise).
        compute: how the SNNs compute a training step: "sparse" (the event-driven CPU engine,
            :mod:`spikegyro.snn.sparse`), "dense" (the batch torch path) or "auto" (sparse on a
            CPU in one process, dense on CUDA or under torchrun). The ANNs are always dense.
        surrogate_cut: bound of the SNN's surrogate gradient, as a share of its peak (0 =
            SLAYER's unbounded pdf); None: 0.2 with the sparse engine (which needs a cut above
            exp(−1/0.3) ≈ 0.036), 0 with the dense path. Equal cuts give equal gradients.
        amp: "bf16" runs the ANNs' forward passes in bfloat16 autocast (weights, optimizer and
            loss stay float32; no loss scaling is needed with bfloat16), "off" in float32;
            "auto" (the default) is "bf16" for an ANN on a CPU with bfloat16 instructions
            (:func:`~spikegyro.train.throughput.resolve_amp`), else "off". The SNN stays in
            float32: its threshold crossings are exact comparisons.
        bare_steps: at the end of the run, time this many bare training steps (same step on one
            batch already on the device) to report beside the run's samples/s (0 = off).
        sim: SimConfig overrides for online mode (dict; see ``spikegyro simulate``).
        tensorboard: also write TensorBoard scalars (needs the tensorboard package).
        real: real recordings (any format the project reads) trained on as unlabeled windows
            with a self-supervised loss (:mod:`spikegyro.train.selfsup`); None: none.
        real_calib: their calibration: a file or ``fx,fy,cx,cy`` (pixels), one for all or one
            per recording (None: an Event Camera Dataset folder's calib.txt).
        real_share: share of each batch's windows drawn from ``real`` (1: real windows only,
            no simulated data needed).
        real_loss: "contrast" (1 − contrast gain of the events warped by the output) or
            "teacher" (Euclidean error to contrast maximization's estimates).
        real_weight: weight of the real windows' loss against the simulated windows' loss.
        real_span_ms: events of at least this many ms before each reference step are warped
            (longer where the motion is slow; see ``ContrastLossConfig``).
        real_holdout: the last share of each recording, held out to validate on by contrast.
        real_start, real_end: the part of each real recording used, seconds after its first
            event (None: to its last event).
        clock: the SNN's clock: "paper" (fixed 1 ms steps) or an event clock "events:N" /
            "events:N:MIN-MAX" (a step closes after N events, within MIN-MAX ms;
            :mod:`spikegyro.events.clock`). On an event clock the window lengths and loss
            starts count steps.
    """

    preset: str = "paper"
    data: str = ""
    online: bool = False
    out: str = ""
    model: str = "snn6"
    input: str = ""
    model_kwargs: dict[str, Any] | None = None
    init: str = ""
    freeze: int = 0
    learn_tau: bool = False
    sensor: tuple[int, int] = (240, 180)
    scale: float = 1.0
    window_ms: int = 100
    num_bins: int = 5
    target_ms: int = 20
    loss_start_step: int = 50
    train_window_ms: int = 0
    train_loss_start_step: int = 0
    batch_size: int = 16
    lr: float = 1e-4
    lr_schedule: str = "constant"
    lr_min_factor: float = 0.05
    warmup_steps: int = 0
    grad_clip: float = 0.0
    iterations: int = 240_000
    max_minutes: float = 0.0
    patience: int = 0
    hflip: float = 0.5
    vflip: float = 0.5
    time_reverse: float = 0.5
    event_keep_min: float = 1.0
    noise_events_hz: float = 0.0
    centre_crop: float = 0.0
    seed: int = 0
    val_every: int = 2000
    val_windows: int = 0
    val_sequences: int = 20
    log_every: int = 50
    num_workers: int = 4
    threads: int = 0
    device: str = "auto"
    data_path: str = "auto"
    amp: str = "auto"
    compute: str = "auto"
    surrogate_cut: float | None = None
    bare_steps: int = 10
    sim: dict[str, Any] | None = None
    tensorboard: bool = False
    real: list[str] | None = None
    real_calib: list[str] | None = None
    real_share: float = 0.5
    real_loss: str = "contrast"
    real_weight: float = 1.0
    real_span_ms: float = 40.0
    real_holdout: float = 0.2
    real_start: float = 0.0
    real_end: float | None = None
    clock: str = "paper"

    def __post_init__(self) -> None:
        Clock.parse(self.clock)  # a clear error for a malformed --clock
        if self.model not in MODEL_INPUTS:
            raise InputError(f"--model {self.model}: choose one of {', '.join(MODEL_INPUTS)}.")
        if not self.input:
            object.__setattr__(self, "input", MODEL_INPUTS[self.model])
        if (self.input == "spikes") != (MODEL_INPUTS[self.model] == "spikes"):
            raise InputError(
                f"--model {self.model} with --input {self.input}: the SNN takes spikes, the "
                "ANNs take voxel or frames."
            )
        if self.data_path not in DATA_PATHS:
            choices = ", ".join(DATA_PATHS)
            raise InputError(f"--data-path {self.data_path}: choose one of {choices}.")
        if self.amp not in AMP_MODES:
            raise InputError(f"--amp {self.amp}: choose one of {', '.join(AMP_MODES)}.")
        if self.amp == "bf16" and self.input == "spikes":
            raise InputError(
                f"--amp {self.amp} with --model {self.model}: mixed precision is for the ANNs; "
                "the SNN's threshold crossings need float32 (use --amp off)."
            )
        if self.freeze and self.input != "spikes":
            raise InputError(
                f"--freeze {self.freeze} with --model {self.model}: freezing layers is for the "
                "SNNs (the ANNs' frozen batch norms would still learn their statistics)."
            )
        if self.learn_tau and self.input != "spikes":
            raise InputError(
                f"--learn-tau with --model {self.model}: time constants are the SNNs' (τs, τr); "
                "the ANNs have none."
            )
        if not 0 <= self.freeze <= len(SNN6_LAYERS):
            raise InputError(
                f"--freeze {self.freeze}: SNN-6 has {len(SNN6_LAYERS)} spiking layers; freeze 0 "
                f"to {len(SNN6_LAYERS)} of them."
            )
        self._check_compute()
        if self.bare_steps < 0:
            raise InputError(f"--bare-steps {self.bare_steps}: must be 0 (off) or positive.")
        if self.lr_schedule not in ("constant", "cosine"):
            raise InputError(f"--lr-schedule {self.lr_schedule}: use constant or cosine.")
        if not self.train_window_ms:
            object.__setattr__(self, "train_window_ms", self.window_ms)
        if not self.train_loss_start_step:
            start = round(self.loss_start_step * self.train_window_ms / self.window_ms)
            object.__setattr__(self, "train_loss_start_step", start)
        for name, start, window in (
            ("loss-start-step", self.loss_start_step, self.window_ms),
            ("train-loss-start-step", self.train_loss_start_step, self.train_window_ms),
        ):
            if not 0 <= start < window:
                raise InputError(f"--{name} {start}: must lie in 0..{window - 1}.")
        for name in ("batch_size", "iterations", "val_every", "log_every", "window_ms"):
            if getattr(self, name) <= 0:
                raise InputError(f"--{name.replace('_', '-')}: must be positive.")
        if not 0.0 <= self.event_keep_min <= 1.0:
            raise InputError(f"--event-keep-min {self.event_keep_min}: must lie in 0..1.")
        if self.noise_events_hz < 0:
            raise InputError(f"--noise-events-hz {self.noise_events_hz}: must be >= 0.")
        if not 0.0 <= self.centre_crop <= 1.0:
            raise InputError(f"--centre-crop {self.centre_crop}: a probability, must lie in 0..1.")
        self._check_real()
        if not self.data and not self.online and not self.real_only:
            raise InputError("train: give --data DIR (a simulated dataset) or --online.")
        self._check_ranges()
        check_device(self.device)
        from spikegyro.models.registry import check_model_kwargs

        # the trainer adds the input channels and outputs, so only what is given is bound here
        check_model_kwargs(self.model, dict(self.model_kwargs or {}), partial=True)
        object.__setattr__(self, "sensor", tuple(int(v) for v in self.sensor))

    def _check_compute(self) -> None:
        if self.compute not in COMPUTE_MODES:
            raise InputError(f"--compute {self.compute}: choose one of {', '.join(COMPUTE_MODES)}.")
        if self.compute == "sparse" and self.input != "spikes":
            raise InputError(
                f"--compute sparse with --model {self.model}: the event-driven engine trains the "
                "SNNs; the ANNs use --compute dense."
            )
        if self.compute == "sparse" and self.device.startswith("cuda"):
            raise InputError(
                f"--compute sparse with --device {self.device}: the event-driven engine runs on "
                "the CPU; use --compute dense on a GPU."
            )
        cut = self.surrogate_cut
        if cut is not None and not 0.0 <= cut < 1.0:
            raise InputError(f"--surrogate-cut {cut}: a share of the peak, must lie in [0, 1).")
        if self.compute == "sparse" and cut is not None and cut <= SPARSE_MIN_CUT:
            raise InputError(
                f"--surrogate-cut {cut} with --compute sparse: the event-driven engine needs a "
                f"cut above {SPARSE_MIN_CUT:.4f} (a support that excludes rest; default "
                f"{SPARSE_DEFAULT_CUT})."
            )

    @property
    def real_only(self) -> bool:
        """Whether every training window is a real one (no simulated data)."""
        return bool(self.real) and self.real_share >= 1.0

    def real_count(self) -> int:
        """Real windows in each batch (0 without ``real``)."""
        if not self.real:
            return 0
        return min(self.batch_size, max(1, round(self.batch_size * self.real_share)))

    def _check_real(self) -> None:
        from spikegyro.train.selfsup import LOSSES

        if not self.real:
            return
        if self.input != "spikes":
            raise InputError(
                f"--real with --model {self.model}: the self-supervised loss scores an SNN's "
                "per-millisecond output; the ANNs predict window means."
            )
        if not 0.0 < self.real_share <= 1.0:
            raise InputError(f"--real-share {self.real_share}: must lie in (0, 1].")
        if self.real_loss not in LOSSES:
            raise InputError(f"--real-loss {self.real_loss}: choose one of {', '.join(LOSSES)}.")
        if not self.real_weight > 0:
            raise InputError(f"--real-weight {self.real_weight}: must be > 0.")
        if self.real_start < 0 or (self.real_end is not None and self.real_end <= self.real_start):
            raise InputError(
                f"--real-start {self.real_start} / --real-end {self.real_end}: the start must be "
                ">= 0 s and the end after it."
            )
        if not 0 < self.real_span_ms <= 1000:
            raise InputError(f"--real-span-ms {self.real_span_ms}: must lie in (0, 1000] ms.")

    def resolved_cut(self, compute: str) -> float:
        """The surrogate cut a run with ``compute`` ("sparse" or "dense") uses."""
        if self.surrogate_cut is not None:
            return self.surrogate_cut
        return SPARSE_DEFAULT_CUT if compute == "sparse" else 0.0

    def _check_ranges(self) -> None:
        if not (self.lr >= 0 and math.isfinite(self.lr)):
            raise InputError(f"--lr {self.lr}: the learning rate must be a number >= 0.")
        for name in ("hflip", "vflip", "time_reverse", "lr_min_factor"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise InputError(
                    f"--{name.replace('_', '-')} {getattr(self, name)}: must lie in 0..1."
                )
        for name in ("warmup_steps", "grad_clip", "val_windows", "num_workers", "threads",
                     "patience"):  # fmt: skip
            if getattr(self, name) < 0:
                raise InputError(f"--{name.replace('_', '-')} {getattr(self, name)}: must be >= 0.")
        if self.max_minutes < 0:
            raise InputError(f"--max-minutes {self.max_minutes}: must be >= 0 (0: no limit).")

    def as_dict(self) -> dict[str, Any]:
        out = asdict(self)
        out["sensor"] = list(self.sensor)
        return out

    def to_json(self) -> str:
        return json.dumps(self.as_dict(), indent=2, sort_keys=True)


PRESETS: dict[str, dict[str, Any]] = {
    "paper": {},
    # Chosen from measurements on the shared 2-core development machine (BENCHMARKS.md,
    # "Training"). SNN-6 at 120x90: 2.3 CPU-seconds per step of 8 windows of 40 ms. Higher
    # learning rates destabilise the SNN (one Adam step at 1e-3 multiplies the loss on the same
    # batch by 3.6; at 1e-4 it falls steadily), so the paper's constant 1e-4 stays; the short
    # budget is spent on more, smaller steps of shorter windows instead. The time budget, not the
    # iteration count, ends the run on a slow machine. ANNs learn faster with --lr 1e-3.
    # Training windows must still reach the network's steady state: fed spikes from step 0,
    # SNN-6's layer 5 starts firing at ~10 ms and its τs = 8 readout is at ~50 % of its final
    # value at 20 ms and ~95 % at 45 ms, while validation scores steps 50-99 of 100 ms windows.
    # A loss from step 20 of 40 ms windows taught the ramp, not the steady state (val 1.09-1.26),
    # so the loss covers steps 45-59 of 60 ms windows.
    "cpu": {
        "scale": 0.5,
        "train_window_ms": 60,
        "train_loss_start_step": 45,
        "batch_size": 8,
        "lr": 1e-4,
        "grad_clip": 1.0,
        # On an idle 2-core machine a step takes ~0.3-0.5 s: the time budget ends the run.
        "iterations": 6000,
        "max_minutes": 10.0,
        "val_every": 500,
        "val_windows": 25,
        "log_every": 5,
        "num_workers": 0,
        "bare_steps": 3,
    },
    # The paper's schedule for real cameras: online data from the davis240c sensor preset (wide
    # thresholds, noise, hot pixels, bandwidth, lens; sparse and office scenes) and event-density
    # augmentation, since a real DAVIS240C gives 0.2 to 5.6 M events/s (docs/simulator.md).
    "sim2real": {
        "online": True,
        "sim": {"sensor": "davis240c"},
        "event_keep_min": 0.2,
        "noise_events_hz": 1.0,
        "centre_crop": 0.25,
    },
}


def field_names() -> list[str]:
    return [f.name for f in fields(TrainConfig)]


def resolve_config(preset: str, overrides: dict[str, Any]) -> TrainConfig:
    """The preset's values with every non-None override applied on top."""
    if preset not in PRESETS:
        raise InputError(f"--preset {preset}: choose one of {', '.join(PRESETS)}.")
    unknown = set(overrides) - set(field_names())
    if unknown:
        raise InputError(f"unknown training option(s): {', '.join(sorted(unknown))}.")
    values = {"preset": preset, **PRESETS[preset]}
    values.update({k: v for k, v in overrides.items() if v is not None})
    return TrainConfig(**values)


def load_config(text: str) -> TrainConfig:
    """Rebuild a config from its ``config.json`` text (for resuming)."""
    data = json.loads(text)
    data["sensor"] = tuple(data.get("sensor", (240, 180)))
    return TrainConfig(**data)
