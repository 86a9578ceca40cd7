"""``spikegyro evaluate``'s library: one model and the mean predictor scored on a dataset split.

:func:`run_evaluation` runs one model (a checkpoint, the paper's official weights, or contrast
maximization) and the mean predictor over a split's fixed windows in four steps: plan (every
input checked, nothing run or written: :func:`plan_evaluation`), predict (the models run:
:func:`predict_evaluation`), score (:func:`score_evaluation`, the metrics of
:mod:`spikegyro.metrics`) and write (:func:`write_evaluation`). It writes into ``OUT``:

- ``metrics.json``: overall per-ms (``metrics``), per-20-ms-window (``window_metrics``), per-axis
  and per-speed-bin metrics of the model (key ``model``) and of the mean predictor (key ``mean``),
  the SNN's spike statistics, data summary and warnings;
- ``predictions.npz``: ``pred``, ``gt`` (n, T, 3) rad/s, ``mean_omega`` (3,) rad/s, ``sources``,
  ``t_start_us``, ``num_events``, so ``report`` and re-analysis never rerun a model;
- ``bins.png`` (paper Fig. 4), ``axes.png`` (Fig. 5), ``window_<i>.png`` (Fig. 3);
- ``report.html`` (self-contained) and ``report.md``.

``spikegyro report`` (:mod:`spikegyro.evaluate.compare`) reads several such folders into the
paper's Table I.
"""

from __future__ import annotations

import itertools
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from rich.console import Console
from rich.progress import Progress

from spikegyro import metrics
from spikegyro.baselines.mean import mean_predictions, training_mean_omega
from spikegyro.checks import check_device, check_output_dir
from spikegyro.errors import InputError, check_interrupt
from spikegyro.evaluate import figures
from spikegyro.evaluate.bins import (
    SPEED_BIN_EDGES_DEG_S,
    bins_json,
    empty_bins,
    per_bin_metrics,
)
from spikegyro.evaluate.compare import METRICS_FORMAT, checkpoint_meta
from spikegyro.evaluate.console import print_summary, write_json
from spikegyro.evaluate.kinds import kind_table, per_kind_metrics, window_scene_kinds
from spikegyro.evaluate.report import (
    Block,
    FigureRef,
    axis_table,
    bin_table,
    display_name,
    overall_table,
    write_report,
)
from spikegyro.evaluate.spikes import spike_statistics, spike_table
from spikegyro.events.clock import Clock
from spikegyro.events.core import EventArray
from spikegyro.events.io import atomic_dir, atomic_path
from spikegyro.events.plot import plot_events_and_omega
from spikegyro.models.official import load_official
from spikegyro.models.registry import (
    CHECKPOINT_FORMAT,
    PRETRAINED_SNN6,
    load_checkpoint,
    resolve_checkpoint,
)
from spikegyro.stream.clocked import clocked_per_ms
from spikegyro.stream.engine import load_engine
from spikegyro.stream.predict import clocked_predictor
from spikegyro.train.data import InputSpec, Window, fixed_windows, with_clock
from spikegyro.train.infer import predict_windows, spec_of

MODEL_CHOICES = ("cmax",)
DEFAULT_EXAMPLES = 3


PAPER_WINDOW_MS = 100
"""The paper's evaluation windows, ms (an event-clock network is scored on them too)."""

def _is_official(path: Path) -> bool:
    """Whether ``path`` holds the official repository's weights rather than our format."""
    try:
        raw = torch.load(path, map_location="cpu", weights_only=True)
    except Exception:  # read_checkpoint will explain what is wrong with the file
        return False
    if not isinstance(raw, dict) or raw.get("format") == CHECKPOINT_FORMAT:
        return False
    return "model_state_dict" in raw or any(str(k).endswith("conv1.weight") for k in raw)


def load_model(checkpoint: str | os.PathLike) -> tuple[torch.nn.Module, dict[str, Any], str]:
    """Load a spikegyro checkpoint (a file or a bundled name) or the paper's official one; returns
    (model, payload, name).

    The official SNN-6 takes the paper's input: 100 ms of 240x180 spikes, omega every 1 ms.
    """
    path = resolve_checkpoint(checkpoint)
    if _is_official(path):
        payload = {"model": "snn6", "input": InputSpec().as_dict(), "extra": {"official": True}}
        return load_official(path), payload, "SNN-6 (official)"
    model, payload = load_checkpoint(path)
    return model, payload, display_name(payload)


def _check_resolution(spec: InputSpec, windows: list[Window], checkpoint: Path) -> None:
    ev = windows[0].events
    if (ev.width, ev.height) != tuple(spec.sensor):
        raise InputError(
            f"{checkpoint}: the model was trained on {spec.sensor[0]}x{spec.sensor[1]} events but "
            f"{windows[0].source} is {ev.width}x{ev.height}; evaluate on data from the same "
            "sensor size (or simulate the dataset at the checkpoint's resolution)."
        )


def choose_examples(windows: list[Window], count: int) -> list[int]:
    """Windows for the qualitative figures: among windows holding events, those whose mean true
    speed over the evaluated steps is closest to evenly spaced quantiles (slow ... fast)."""
    candidates = [i for i, w in enumerate(windows) if len(w.events)]
    if not candidates or count <= 0:
        return []
    speed = [
        np.linalg.norm(windows[i].omega[metrics.EVAL_START_STEP :], axis=-1).mean()
        for i in candidates
    ]
    order = np.argsort(speed, kind="stable")
    quantiles = np.linspace(0.1, 0.9, count) if count > 1 else np.array([0.5])
    picks = order[np.round(quantiles * (len(order) - 1)).astype(int)]
    return sorted({candidates[int(i)] for i in picks})


def _subject(
    checkpoint: str | os.PathLike | None,
) -> tuple[tuple[torch.nn.Module, dict[str, Any]] | None, InputSpec, str, dict[str, Any]]:
    """What is evaluated: (model and payload or None for CMax, input spec, name, description)."""
    if checkpoint is None:
        info = {
            "method": "cmax",
            "source": "contrast maximization (spikegyro.cmax), offline: centred windows",
        }
        return None, InputSpec(), "CMax", info
    net, payload, name = load_model(checkpoint)
    spec = spec_of(payload)
    info = {
        "method": "checkpoint",
        "source": str(checkpoint),
        "checkpoint_model": payload.get("model"),
        "checkpoint_meta": checkpoint_meta(payload),
        "input": spec.as_dict(),
    }
    return (net, payload), spec, name, info


def _model_results(
    pred: np.ndarray, gt: np.ndarray, kinds: list[str], edges: tuple[float, ...]
) -> dict[str, Any]:
    return {
        "metrics": metrics.summary(pred, gt),
        "window_metrics": metrics.window_metrics(pred, gt),
        "per_bin": per_bin_metrics(pred, gt, edges),
        "per_scene_kind": per_kind_metrics(pred, gt, kinds),
    }


def _finite(pred: np.ndarray, name: str, warnings: list[str]) -> tuple[np.ndarray, int]:
    bad = ~np.isfinite(pred)
    count = int(bad.any(axis=-1).sum())
    if count:
        warnings.append(
            f"{name} gave {count} non-finite predictions (steps); they are scored as 0 rad/s."
        )
        pred = np.where(bad, 0.0, pred)
    return pred, count


def _mean_omega(data_dir: Path, warnings: list[str]) -> tuple[np.ndarray, str]:
    try:
        return training_mean_omega(data_dir, "train"), str(data_dir / "train")
    except InputError as exc:
        warnings.append(f"mean predictor uses omega = 0 (close to the paper's mean): {exc}")
        return np.zeros(3), "zero (no training split)"


def _write_predictions(
    path: Path, windows: list[Window], pred: np.ndarray, gt: np.ndarray, mean_omega: np.ndarray
) -> None:
    """predictions.npz: everything needed to re-score without rerunning the model."""
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        np.savez_compressed(
            f,
            pred=pred,
            gt=gt,
            mean_omega=mean_omega,
            sources=np.array([w.source for w in windows]),
            t_start_us=np.array([w.t_start_us for w in windows], dtype=np.int64),
            num_events=np.array([len(w.events) for w in windows], dtype=np.int64),
        )


def _predict(
    model_spec: tuple[torch.nn.Module, dict[str, Any]] | None,
    windows: list[Window],
    batch_size: int,
    device: str,
    console: Console,
) -> np.ndarray:
    with Progress(console=console, transient=True) as bar:
        task = bar.add_task("predicting", total=len(windows))
        if model_spec is None:
            from spikegyro.cmax.offline import predict_windows_offline

            return predict_windows_offline(
                windows, progress=lambda done, _total: bar.update(task, completed=done)
            )
        model, payload = model_spec
        model.to(device)
        return predict_windows(
            model,
            payload,
            windows,
            batch_size,
            device=device,
            progress=lambda done: bar.update(task, completed=done),
        )


def _predict_clocked(
    checkpoint: Path, spec: InputSpec, windows: list[Window], console: Console
) -> np.ndarray:
    """An event-clock network over each sequence as one stream, as ``predict`` runs it (its
    steps may be longer than a window's first 50 ms), read at every real millisecond of the
    windows, on the exact event-driven stream; (n, T, 3) rad/s."""
    engine, _ = load_engine(checkpoint)
    out = np.zeros((len(windows), windows[0].num_steps, 3))
    groups = [list(g) for _, g in itertools.groupby(range(len(windows)),
                                                     key=lambda i: windows[i].source)]  # fmt: skip
    with Progress(console=console, transient=True) as bar:
        task = bar.add_task("predicting (event clock)", total=len(windows))
        for group in groups:
            check_interrupt()
            t0 = windows[group[0]].t_start_us
            events = EventArray.concatenate([windows[i].events for i in group])
            events = events if spec.scale == 1.0 else events.rescale(spec.scale)
            predictor = clocked_predictor(engine, spec.as_dict(), t0)
            series = clocked_per_ms(predictor, events, t0, out.shape[1] * len(group))
            out[group] = series.reshape(len(group), out.shape[1], 3)
            bar.update(task, advance=len(group))
    return out


def _example_figures(
    out_dir: Path,
    windows: list[Window],
    pred: np.ndarray,
    examples: list[int],
    name: str,
) -> list[FigureRef]:
    """The paper's Fig. 3 for each chosen window; returns their report entries."""
    refs = []
    for i in examples:
        w = windows[i]
        ends_s = (w.t_start_us + 1000 * np.arange(1, w.num_steps + 1)) / 1e6
        file = f"window_{i:05d}.png"
        plot_events_and_omega(
            w.events,
            ends_s,
            w.omega,
            pred[i],
            out=out_dir / file,
            title=f"{name}: window {i} ({Path(w.source).name}, "
            f"t = {w.t_start_us / 1e3:g} to {w.t_end_us / 1e3:g} ms)",
            t0_s=w.t_start_us / 1e6,
        )
        refs.append(
            FigureRef(
                f"Window {i}: {len(w.events):,} events in space-time (ON red, OFF blue) above "
                f"the true (solid) and {name}'s predicted (dashed) angular velocity on three "
                "axes (paper Fig. 3); metrics count from 50 ms on.",
                file,
            )
        )
    return refs


@dataclass(frozen=True)
class EvalOptions:
    """What ``spikegyro evaluate`` scores and how (the arguments of :func:`run_evaluation`)."""

    data_dir: Path
    checkpoint: Path | None = None
    split: str = "test"
    out_dir: Path = Path("evaluation")
    model: str | None = None
    name: str | None = None
    batch_size: int = 8
    device: str | None = None
    limit: int | None = None
    examples: list[int] | None = None
    num_examples: int = DEFAULT_EXAMPLES
    spike_windows: int = 16
    speed_bins: tuple[float, ...] = SPEED_BIN_EDGES_DEG_S
    clock: str | None = None


@dataclass
class EvalPlan:
    """A checked evaluation, before any model runs: the model (None for CMax), its input spec
    and names, the windows, the example windows for the figures, and the warnings so far."""

    options: EvalOptions
    subject: tuple[torch.nn.Module, dict[str, Any]] | None
    spec: InputSpec
    name: str
    info: dict[str, Any]
    windows: list[Window]
    examples: list[int]
    device: str
    warnings: list[str] = field(default_factory=list)
    checkpoint: Path | None = None


@dataclass
class EvalPredictions:
    """What the models answered: ``pred`` and ``gt`` (n, T, 3) rad/s (non-finite predictions
    already scored as 0, ``nonfinite`` of them), the mean predictor's omega (3,) rad/s and its
    source, the SNN's spike statistics (None for other models), and for CMax (scored offline)
    the live engine's per-ms ω beside it (None for other models)."""

    pred: np.ndarray
    gt: np.ndarray
    nonfinite: int
    mean_omega: np.ndarray
    mean_source: str
    spikes: dict[str, Any] | None
    live: np.ndarray | None = None


def _check_options(options: EvalOptions) -> tuple[Path | None, str]:
    """The checkpoint to load (None: CMax) and the torch device; InputError on bad options."""
    check_output_dir(options.out_dir)
    if options.batch_size < 1:
        raise InputError(f"--batch-size {options.batch_size}: must be at least 1.")
    check_device(options.device)
    checkpoint, model = options.checkpoint, options.model
    if checkpoint is not None and model is not None:
        raise InputError("give either --checkpoint CKPT or --model cmax, not both.")
    if checkpoint is None and model is None:
        checkpoint = PRETRAINED_SNN6
    if checkpoint is not None:
        checkpoint = resolve_checkpoint(checkpoint)
    if model is not None and model not in MODEL_CHOICES:
        raise InputError(f"--model {model}: choose one of {', '.join(MODEL_CHOICES)}.")
    return checkpoint, options.device or ("cuda" if torch.cuda.is_available() else "cpu")


def _data_warnings(windows: list[Window], spec: InputSpec, name: str) -> list[str]:
    warnings = []
    if spec.output == "window_mean" and metrics.WINDOW_METRIC_MS % spec.target_ms:
        warnings.append(
            f"{name} predicts means over {spec.target_ms} ms, which do not tile the "
            f"{metrics.WINDOW_METRIC_MS} ms windows of the per-window metrics."
        )
    empty = sum(1 for w in windows if not len(w.events))
    if empty:
        warnings.append(
            f"{empty} of {len(windows)} windows hold no events; the "
            "model sees no input there, and their errors still count."
        )
    return warnings


def plan_evaluation(options: EvalOptions) -> EvalPlan:
    """Check every input and load the model and the windows; nothing is run or written.

    Raises:
        InputError: on a bad option, checkpoint, split or example index.
    """
    checkpoint, device = _check_options(options)
    subject, spec, default_name, info = _subject(checkpoint)
    if options.clock is not None:
        spec = with_clock(spec, Clock.parse(options.clock))
        info["input"] = spec.as_dict()
    name = options.name or default_name
    if not spec.step_clock.is_paper:
        name = f"{name}, {spec.step_clock.label}"
    # an event-clock network is scored on the paper's windows, per real millisecond
    window_ms = spec.window_ms if spec.step_clock.is_paper else PAPER_WINDOW_MS
    windows = fixed_windows(options.data_dir, options.split, window_ms)
    if options.limit is not None:
        windows = windows[: max(0, options.limit)]
    if not windows:
        raise InputError(
            f"{options.data_dir / options.split}: no windows of {spec.window_ms} ms to evaluate."
        )
    if checkpoint is not None:
        _check_resolution(spec, windows, Path(checkpoint))
    picks = options.examples
    if picks is None:
        picks = choose_examples(windows, options.num_examples)
    if bad := [i for i in picks if not 0 <= i < len(windows)]:
        raise InputError(f"--example {bad[0]}: there are only {len(windows)} windows (0-based).")
    return EvalPlan(
        options,
        subject,
        spec,
        name,
        info,
        windows,
        picks,
        device,
        _data_warnings(windows, spec, name),
        None if checkpoint is None else Path(checkpoint),
    )


def _spike_statistics(plan: EvalPlan, console: Console) -> dict[str, Any] | None:
    """The SNN's spiking activity on the first windows with events (None for other models)."""
    if plan.subject is None or not hasattr(plan.subject[0], "forward_with_spikes"):
        return None
    busy = [w for w in plan.windows if len(w.events)][: plan.options.spike_windows]
    with Progress(console=console, transient=True) as bar:
        task = bar.add_task("spike statistics", total=len(busy))
        return spike_statistics(
            plan.subject[0],
            plan.spec,
            busy,
            plan.device,
            progress=lambda done: bar.update(task, completed=done),
        )


def predict_evaluation(plan: EvalPlan, console: Console) -> EvalPredictions:
    """Run the model over the plan's windows (and the SNN's spike statistics); the mean
    predictor's omega comes from the training split (0 without one, with a warning)."""
    windows = plan.windows
    gt = np.stack([w.omega for w in windows]).astype(np.float64)
    if plan.checkpoint is not None and not plan.spec.step_clock.is_paper:
        raw = _predict_clocked(plan.checkpoint, plan.spec, windows, console)
    else:
        raw = _predict(plan.subject, windows, plan.options.batch_size, plan.device, console)
    pred, nonfinite = _finite(raw.astype(np.float64), plan.name, plan.warnings)
    mean_omega, mean_source = _mean_omega(plan.options.data_dir, plan.warnings)
    spikes = _spike_statistics(plan, console)
    live = _cmax_live(windows, console) if plan.subject is None else None
    return EvalPredictions(pred, gt, nonfinite, mean_omega, mean_source, spikes, live)


def _cmax_live(windows: list[Window], console: Console) -> np.ndarray:
    """The live (causal) CMax engine's per-ms ω over the windows, reported beside the offline
    one that the CMax row scores."""
    from spikegyro.cmax import series

    with Progress(console=console, transient=True) as bar:
        task = bar.add_task("CMax, live engine", total=len(windows))
        return series.predict_windows(
            windows,
            progress=lambda done, _total: bar.update(task, completed=done),
            first_step=metrics.EVAL_START_STEP,
        )


def _data_summary(plan: EvalPlan, window_ms: int) -> dict[str, Any]:
    windows = plan.windows
    num_events = np.array([len(w.events) for w in windows], dtype=np.int64)
    return {
        "dir": str(plan.options.data_dir),
        "split": plan.options.split,
        "windows": len(windows),
        "window_ms": window_ms,
        "sensor": [windows[0].events.width, windows[0].events.height],
        "eval_from_step": metrics.EVAL_START_STEP,
        "min_speed_deg_s": metrics.MIN_SPEED_DEG_S,
        "windows_without_events": int((num_events == 0).sum()),
        "events_per_window": {
            "mean": float(num_events.mean()),
            "median": float(np.median(num_events)),
            "min": int(num_events.min()),
            "max": int(num_events.max()),
        },
    }


def score_evaluation(plan: EvalPlan, predicted: EvalPredictions) -> dict[str, Any]:
    """The metrics of the model and of the mean predictor: the dict ``metrics.json`` holds."""
    pred, gt, warnings = predicted.pred, predicted.gt, plan.warnings
    kinds, edges = window_scene_kinds(plan.windows), plan.options.speed_bins
    model_res = {"name": plan.name, **plan.info, **_model_results(pred, gt, kinds, edges)}
    model_res["nonfinite_predictions"] = predicted.nonfinite
    if predicted.spikes is not None:
        model_res["spikes"] = predicted.spikes
    if predicted.live is not None:
        model_res["live"] = {
            "name": f"{plan.name} (live)",
            "method": "cmax_live",
            "source": "contrast maximization (spikegyro.cmax), live: causal windows",
            **_model_results(predicted.live, gt, kinds, edges),
        }
    mean_res = {
        "name": "Mean",
        "method": "mean",
        "source": predicted.mean_source,
        "omega_rad_s": predicted.mean_omega.tolist(),
        **_model_results(mean_predictions(predicted.mean_omega, *gt.shape[:2]), gt, kinds, edges),
    }
    if empty := empty_bins(model_res["per_bin"]):
        warnings.append(f"no evaluated step in speed bin(s) {', '.join(empty)} deg/s; left empty.")
    if model_res["metrics"]["median_relative_error"] is None:
        warnings.append("every true speed is under 1 deg/s: the relative error is undefined.")
    return {
        "format": METRICS_FORMAT,
        "data": _data_summary(plan, int(gt.shape[1])),
        "bins": bins_json(edges),
        "model": model_res,
        "mean": mean_res,
        "warnings": warnings,
    }


def write_evaluation(plan: EvalPlan, predicted: EvalPredictions, result: dict[str, Any]) -> None:
    """Write every output into the plan's folder at once (all or nothing)."""
    with atomic_dir(plan.options.out_dir) as staging:
        _write_predictions(
            staging / "predictions.npz",
            plan.windows,
            predicted.pred,
            predicted.gt,
            predicted.mean_omega,
        )
        write_json(staging / "metrics.json", result)
        refs = _example_figures(staging, plan.windows, predicted.pred, plan.examples, plan.name)
        _evaluation_report(staging, result, refs)


def run_evaluation(
    data_dir: str | os.PathLike,
    checkpoint: str | os.PathLike | None = None,
    split: str = "test",
    out_dir: str | os.PathLike = "evaluation",
    *,
    model: str | None = None,
    name: str | None = None,
    batch_size: int = 8,
    device: str | None = None,
    limit: int | None = None,
    examples: list[int] | None = None,
    num_examples: int = DEFAULT_EXAMPLES,
    spike_windows: int = 16,
    speed_bins: tuple[float, ...] = SPEED_BIN_EDGES_DEG_S,
    clock: str | None = None,
    console: Console | None = None,
) -> dict[str, Any]:
    """Evaluate a checkpoint (or ``model="cmax"``) and the mean predictor on ``data_dir/split``.

    Args:
        data_dir: dataset folder (``DIR/{train,val,test}/*.h5``); the mean predictor's value is
            the mean ground truth of ``DIR/train``.
        checkpoint: a spikegyro checkpoint or the paper's official one (detected by content).
        split: which split's fixed windows to score.
        out_dir: where the outputs go (see the module docstring).
        model: ``"cmax"`` for contrast maximization (then no checkpoint).
        name: display name overriding the one derived from the checkpoint.
        batch_size: windows per forward pass.
        device: torch device; default CUDA when available.
        limit: score only the first ``limit`` windows (quick looks).
        examples: window indices for the qualitative figures; default ``num_examples`` windows
            spread from slow to fast.
        spike_windows: windows (the first ones with events) used for the SNN spike statistics.
        speed_bins: edges of the speed bins, deg/s (:mod:`spikegyro.evaluate.bins`).
        clock: run the SNN on this clock (:meth:`Clock.parse`) instead of its own.

    Returns:
        The dict written to ``metrics.json``.
    """
    console = console or Console(stderr=True)
    options = EvalOptions(
        Path(data_dir),
        None if checkpoint is None else Path(checkpoint),
        split,
        Path(out_dir),
        model,
        name,
        batch_size,
        device,
        limit,
        examples,
        num_examples,
        spike_windows,
        tuple(speed_bins),
        clock,
    )
    plan = plan_evaluation(options)
    predicted = predict_evaluation(plan, console)
    result = score_evaluation(plan, predicted)
    write_evaluation(plan, predicted, result)
    model = result["model"]
    rows = [model, *([model["live"]] if "live" in model else []), result["mean"]]
    print_summary(console, f"{options.data_dir} / {split}", rows, plan.warnings)
    console.print(f"wrote {options.out_dir}/metrics.json, predictions.npz, report.html, report.md")
    return result


def _evaluation_report(out_dir: Path, result: dict[str, Any], examples: list[FigureRef]) -> None:
    model, mean, data = result["model"], result["mean"], result["data"]
    name = model["name"]
    per_bin = {name: model["per_bin"], "Mean": mean["per_bin"]}
    rows = {name: model, **({model["live"]["name"]: model["live"]} if "live" in model else {})}
    figures.save_figure(
        figures.median_relative_error_per_bin(per_bin, f"{name} vs mean predictor"),
        out_dir / "bins.png",
    )
    figures.save_figure(
        figures.axis_relative_error_boxes(model["per_bin"], name), out_dir / "axes.png"
    )
    blocks: list[Block] = [
        f"Data: {data['dir']} / {data['split']}: {data['windows']:,} windows of "
        f"{data['window_ms']} ms from a {data['sensor'][0]}x{data['sensor'][1]} sensor; metrics "
        f"over steps >= {data['eval_from_step']} ms of each window. Mean predictor: "
        f"{', '.join(f'{v:+.2f}' for v in np.degrees(mean['omega_rad_s']))} deg/s "
        f"(from {mean['source']}).",
        "Median relative error: median of ‖ω − ω̂‖ / ‖ω̂‖ (ω̂: ground truth) over steps with "
        f"‖ω̂‖ ≥ {data['min_speed_deg_s']:g} deg/s. Mean Euclidean error: mean of ‖ω − ω̂‖, "
        'which the paper reports as "RMSE". RMSE: the true root-mean-square of ‖ω − ω̂‖.',
        *[f"Warning: {w}" for w in result["warnings"]],
        "## Overall",
        overall_table(
            {**rows, "Mean": mean},
            "Overall errors; paper columns: Gehrig et al. 2020, Table I, on their own data "
            "(Sun360 panoramas through ESIM), not ours",
        ),
        axis_table({**{k: v["metrics"] for k, v in rows.items()}, "Mean": mean["metrics"]}),
        "## Per speed",
        bin_table(per_bin),
        FigureRef("Median relative error per true-speed bin (paper Fig. 4).", "bins.png"),
        FigureRef(
            f"{name}: signed per-axis relative error per true-speed bin; boxes: quartiles, "
            "whiskers: 1.5 IQR (paper Fig. 5).",
            "axes.png",
        ),
    ]
    blocks += ["## Per scene kind", table] if (table := kind_table([model, mean])) else []
    if "spikes" in model:
        blocks += ["## Spiking activity", spike_table(model["spikes"])]
    if examples:
        blocks += ["## Example windows", *examples]
    write_report(out_dir, f"spikegyro evaluation: {name}", blocks)
