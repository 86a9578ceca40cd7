"""The training loop on a tiny simulated dataset: learning, resume, DDP, the command line."""

from __future__ import annotations

import csv
import json
import os
import signal
import socket
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
import torch.multiprocessing as mp
from scipy.ndimage import gaussian_filter
from typer.testing import CliRunner

from spikegyro.cli import app
from spikegyro.errors import InputError
from spikegyro.evaluate.compare import training_info
from spikegyro.events.io import write_recording
from spikegyro.models.registry import build_model, load_checkpoint
from spikegyro.sim.camera import Camera
from spikegyro.sim.esim import simulate
from spikegyro.sim.panorama import Panorama
from spikegyro.sim.trajectory import random_trajectory
from spikegyro.train import commands as train_commands
from spikegyro.train import distributed
from spikegyro.train.data import model_batch
from spikegyro.train.loop import (
    StepSampler,
    _data_workers,
    input_spec_of,
    model_kwargs_of,
    resume_config,
    train,
    training_samples,
)
from spikegyro.train.loss import angular_velocity_loss
from spikegyro.train.presets import TrainConfig, resolve_config
from spikegyro.train.throughput import RunClock, bare_step_rate, train_step

SIZE = 64  # SNN-6 needs at least 63 px for its five unpadded convolutions
CAMERA = Camera(SIZE, SIZE, fx=56.0, fy=56.0, cx=31.5, cy=31.5)


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    """Four 100 ms sequences (3 train, 1 val) of a random texture."""
    root = tmp_path_factory.mktemp("tiny")
    rng = np.random.default_rng(0)
    texture = gaussian_filter(rng.standard_normal((256, 512)), sigma=2.0, mode="wrap")
    scene = Panorama(np.exp(1.5 * texture / texture.std()), "noise")
    for i, split in enumerate(("train", "train", "train", "val")):
        traj = random_trajectory(np.random.default_rng(10 + i), duration_s=0.1)
        rec = simulate(scene, traj, CAMERA, rng=np.random.default_rng(i))
        write_recording(root / split / f"seq_{i:06d}.h5", rec)
    return root


def tiny_config(dataset: Path, out: Path, **kw) -> TrainConfig:
    values = dict(
        data=str(dataset), out=str(out), model="snn6", sensor=(SIZE, SIZE), window_ms=20,
        loss_start_step=10, batch_size=4, lr=1e-3, iterations=4, val_every=2, log_every=1,
        num_workers=0, device="cpu", threads=1, bare_steps=2,
    )  # fmt: skip
    values.update(kw)
    return resolve_config("paper", values)


@pytest.mark.parametrize(
    ("model", "kwargs"), [("snn6", {}), ("ann6", {"batch_norm": False})], ids=["snn6", "ann6"]
)
def test_one_training_step_lowers_the_loss(dataset, tmp_path, model, kwargs):
    config = tiny_config(dataset, tmp_path, model=model, model_kwargs=kwargs, lr=3e-4)
    spec = input_spec_of(config)
    torch.manual_seed(0)
    net = build_model(model, **model_kwargs_of(config, spec))
    samples = training_samples(config, spec)
    batch = [samples[i] for i in range(4)]
    x, y = model_batch(torch.stack([b[0] for b in batch]), torch.stack([b[1] for b in batch]), spec)
    optimizer = torch.optim.Adam(net.parameters(), lr=config.lr)
    before = angular_velocity_loss(net(x), y, config.loss_start_step)
    optimizer.zero_grad()
    before.backward()
    optimizer.step()
    with torch.no_grad():
        after = angular_velocity_loss(net(x), y, config.loss_start_step)
    assert after.item() < before.item() - 1e-3


def test_bf16_autocast_step_runs_the_convolutions_in_bfloat16_and_learns(dataset, tmp_path):
    config = tiny_config(dataset, tmp_path, model="ann6", amp="bf16", lr=3e-4)
    spec = input_spec_of(config)
    samples = training_samples(config, spec)
    batch = [samples[i] for i in range(4)]
    x, y = model_batch(torch.stack([b[0] for b in batch]), torch.stack([b[1] for b in batch]), spec)
    torch.manual_seed(0)
    net = build_model("ann6", **model_kwargs_of(config, spec))
    reference = build_model("ann6", **model_kwargs_of(config, spec))
    reference.load_state_dict(net.state_dict())
    seen = []
    convs = [m for m in net.modules() if isinstance(m, torch.nn.Conv2d)]
    for conv in convs:
        conv.register_forward_hook(lambda _m, _i, out: seen.append(out.dtype))
    optimizer = torch.optim.Adam(net.parameters(), lr=config.lr)
    first = train_step(net, optimizer, x, y, config.loss_start_step, amp=True)
    assert seen == [torch.bfloat16] * len(convs)
    assert first.dtype == torch.float32
    assert all(p.dtype == torch.float32 for p in net.parameters())
    full = angular_velocity_loss(reference.train()(x), y, config.loss_start_step)
    assert abs(first.item() - full.item()) < 0.02 * full.item()  # bfloat16: 8 bits of mantissa
    losses = [train_step(net, optimizer, x, y, config.loss_start_step, amp=True) for _ in range(3)]
    assert losses[-1].item() < first.item()


def state_of(path: Path) -> dict[str, torch.Tensor]:
    return torch.load(path, map_location="cpu", weights_only=False)["state_dict"]


def assert_same_weights(a: Path, b: Path, atol: float = 0.0) -> None:
    sa, sb = state_of(a), state_of(b)
    assert sa.keys() == sb.keys()
    for k in sa:
        torch.testing.assert_close(sa[k], sb[k], atol=atol, rtol=0)


def test_data_workers_are_capped_at_the_cores_the_process_may_use(monkeypatch):
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1}, raising=False)
    assert [_data_workers(n) for n in (0, 1, 2, 4)] == [0, 1, 2, 2]
    monkeypatch.delattr(os, "sched_getaffinity", raising=False)
    monkeypatch.setattr(os, "cpu_count", lambda: None)
    assert _data_workers(4) == 1


def test_run_writes_its_files_and_resumes_to_the_same_state(dataset, tmp_path):
    kw = dict(warmup_steps=3)  # the scheduler's state crosses the resume point
    straight = train(tiny_config(dataset, tmp_path / "a", **kw), progress=False)
    assert straight.steps == 4
    run = tmp_path / "a"
    for name in ("config.json", "log.csv", "last.pt", "best.pt", "resume.pt", "loss.png"):
        assert (run / name).exists(), name
    saved = json.loads((run / "config.json").read_text())
    assert saved["batch_size"] == 4 and saved["window_ms"] == 20
    with open(run / "log.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert [int(r["step"]) for r in rows] == [1, 2, 3, 4]
    assert rows[1]["val_median_rel"] and rows[3]["val_median_rel"]
    _, payload = load_checkpoint(run / "last.pt")
    assert payload["input"]["representation"] == "spikes" and payload["extra"]["step"] == 4

    # interrupted after 2 steps (as if killed after the checkpoint), then resumed to 4
    first = train(tiny_config(dataset, tmp_path / "b", iterations=2, **kw), progress=False)
    assert first.steps == 2
    config = replace(tiny_config(dataset, tmp_path / "b", **kw))
    resumed = train(config, resume=True, progress=False)
    assert resumed.steps == 4
    assert_same_weights(run / "last.pt", tmp_path / "b" / "last.pt")
    sa = torch.load(run / "resume.pt", weights_only=False)["optimizer"]["state"]
    sb = torch.load(tmp_path / "b" / "resume.pt", weights_only=False)["optimizer"]["state"]
    for k in sa:
        torch.testing.assert_close(sa[k]["exp_avg_sq"], sb[k]["exp_avg_sq"], atol=0, rtol=0)
    with open(tmp_path / "b" / "log.csv", newline="") as f:
        assert [int(r["step"]) for r in csv.DictReader(f)] == [1, 2, 3, 4]

    # --init starts from a checkpoint's weights (lr 0 keeps them) and counts its training on:
    # the report's steps and minutes add the runs a checkpoint was continued from
    init = tiny_config(dataset, tmp_path / "c", init=str(run / "last.pt"), lr=0.0, iterations=1)
    train(replace(init, val_every=1), progress=False)
    assert_same_weights(run / "last.pt", tmp_path / "c" / "last.pt")
    _, again = load_checkpoint(tmp_path / "c" / "last.pt")
    before = again["extra"]["before"]
    assert before == {"steps": 4, "elapsed_s": payload["extra"]["elapsed_s"]}
    info = training_info(again)
    assert info["steps"] == 5
    assert info["minutes"] * 60 == pytest.approx(before["elapsed_s"] + again["extra"]["elapsed_s"])
    chained = tiny_config(dataset, tmp_path / "d", init=str(tmp_path / "c" / "last.pt"),
                          lr=0.0, iterations=2, val_every=1)  # fmt: skip
    train(replace(chained, iterations=1), progress=False)
    train(chained, resume=True, progress=False)  # a resumed run keeps what came before it
    _, third = load_checkpoint(tmp_path / "d" / "last.pt")
    assert third["extra"]["step"] == 2 and training_info(third)["steps"] == 4 + 1 + 2
    assert training_info(payload)["steps"] == 4  # a run from scratch: its own steps

    # an snn6 checkpoint starts an snn6-grid run with the readout spread over the cells
    grid = tiny_config(dataset, tmp_path / "g", model="snn6-grid", model_kwargs={"grid": [1, 2]},
                       init=str(run / "last.pt"), lr=0.0, iterations=1, val_every=1)  # fmt: skip
    train(grid, progress=False)
    _, base = load_checkpoint(run / "last.pt")
    _, tiled = load_checkpoint(tmp_path / "g" / "last.pt")
    torch.testing.assert_close(
        tiled["state_dict"]["conv5.weight"], base["state_dict"]["conv5.weight"]
    )
    torch.testing.assert_close(
        tiled["state_dict"]["fc.weight"],
        base["state_dict"]["fc.weight"].repeat_interleave(2, 1) / 2,
    )


def test_event_data_path_trains_exactly_like_the_dense_path(dataset, tmp_path):
    """Event lists binned by the loop give the same batches, so the same weights, bit for bit
    (training windows longer than the validation windows, binned at their own length)."""
    kw = dict(iterations=3, val_every=3, train_window_ms=30)
    dense = train(tiny_config(dataset, tmp_path / "d", data_path="dense", **kw), progress=False)
    events = train(tiny_config(dataset, tmp_path / "e", data_path="events", **kw), progress=False)
    assert (dense.data_path, events.data_path) == ("dense", "events")
    assert_same_weights(tmp_path / "d" / "last.pt", tmp_path / "e" / "last.pt")
    assert dense.last_loss == events.last_loss
    record = json.loads((tmp_path / "e" / "throughput.json").read_text())
    assert record["data_path"] == "events" and record["run_samples_per_s"] > 0
    assert record["bare_ms_per_step"] > 0
    assert record["run_over_bare"] == pytest.approx(
        record["run_samples_per_s"] / record["bare_samples_per_s"]
    )


def test_bare_step_leaves_the_model_alone_and_the_clock_skips_pauses():
    torch.manual_seed(0)
    net = build_model("ann6", in_channels=2, batch_norm=False)
    before = {k: v.clone() for k, v in net.state_dict().items()}
    x, y = torch.rand(4, 2, 64, 64), torch.rand(4, 3)
    bare = bare_step_rate(net, x, y, windows=2, loss_start_step=0, lr=1e-2, steps=2)
    assert bare.steps == 2 and bare.samples_per_s == pytest.approx(2000 / bare.ms_per_step)
    for k, v in net.state_dict().items():
        assert torch.equal(v, before[k])
    clock = RunClock(samples_per_step=8)
    clock.step()  # the first step only starts the clock
    with clock.paused():
        time.sleep(0.3)
    clock.step()
    assert clock.steps == 1 and clock.busy_s < 0.1
    assert clock.samples_per_s == pytest.approx(8 / clock.busy_s)


def test_time_budget_stops_gracefully_with_a_checkpoint(dataset, tmp_path):
    result = train(
        tiny_config(dataset, tmp_path, iterations=1000, max_minutes=1e-6, val_every=1000),
        progress=False,
    )
    assert result.stopped_early and result.steps == 1
    assert (tmp_path / "last.pt").exists() and result.val


def test_patience_stops_a_run_whose_validation_stopped_improving_and_survives_resume(
    dataset, tmp_path
):
    # lr 0: the weights never change, so no validation after the first improves on it.
    config = tiny_config(dataset, tmp_path, iterations=1000, lr=0.0, val_every=1, patience=2)
    result = train(config, progress=False)
    assert result.out_of_patience and result.stopped_early and not result.interrupted
    assert (result.steps, result.best_step) == (3, 1)
    # The best's step is kept with the run: a resumed run counts from it, not from its resume.
    again = train(replace(config, patience=3), resume=True, progress=False)
    assert (again.steps, again.best_step) == (4, 1) and again.out_of_patience
    # Patience 0 (the default) never stops a run.
    off = train(tiny_config(dataset, tmp_path / "off", lr=0.0, val_every=1), progress=False)
    assert off.steps == 4 and not off.out_of_patience and not off.stopped_early


# ----------------------------------------------------------------------------------- DDP


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _ddp_worker(rank: int, world: int, port: int, config: TrainConfig, out: str) -> None:
    os.environ.update(
        MASTER_ADDR="127.0.0.1", MASTER_PORT=str(port), RANK=str(rank), WORLD_SIZE=str(world),
        LOCAL_RANK=str(rank),
    )  # fmt: skip
    torch.set_num_threads(1)
    ctx = distributed.init_distributed("cpu")
    # (a) one backward pass through DDP on this process's share of step 0's batch
    spec = input_spec_of(config)
    torch.manual_seed(config.seed)
    net = torch.nn.parallel.DistributedDataParallel(
        build_model(config.model, **model_kwargs_of(config, spec))
    )
    samples = training_samples(config, spec)
    idx = list(StepSampler(0, 1, config.batch_size, rank, world))
    batch = [samples[i] for i in idx]
    x, y = model_batch(torch.stack([b[0] for b in batch]), torch.stack([b[1] for b in batch]), spec)
    angular_velocity_loss(net(x), y, config.loss_start_step).backward()
    if rank == 0:
        grads = {n: p.grad for n, p in net.module.named_parameters()}
        torch.save({"grads": grads, "indices": idx}, Path(out) / "ddp_grads.pt")
    distributed.barrier(ctx)
    # (b) the full loop, which joins the same process group
    train(config, progress=False)


def test_ddp_two_processes_match_single_process(dataset, tmp_path):
    # Under torchrun the SNN trains on the dense path; the single process does the same here.
    config = tiny_config(dataset, tmp_path / "ddp", iterations=2, val_every=2, compute="dense")
    (tmp_path / "ddp").mkdir()
    mp.spawn(
        _ddp_worker, args=(2, _free_port(), config, str(tmp_path / "ddp")), nprocs=2, join=True
    )
    single = replace(config, out=str(tmp_path / "single"))
    spec = input_spec_of(single)
    torch.manual_seed(single.seed)
    net = build_model(single.model, **model_kwargs_of(single, spec))
    samples = training_samples(single, spec)
    idx = list(StepSampler(0, 1, single.batch_size, 0, 1))
    batch = [samples[i] for i in idx]
    x, y = model_batch(torch.stack([b[0] for b in batch]), torch.stack([b[1] for b in batch]), spec)
    angular_velocity_loss(net(x), y, single.loss_start_step).backward()
    ddp = torch.load(tmp_path / "ddp" / "ddp_grads.pt", weights_only=False)
    assert ddp["indices"] == idx[: len(idx) // 2]  # rank 0 took the first half
    # Norm-wise comparisons: batch size changes float rounding, and a membrane potential within
    # rounding of the threshold may flip one spike, which moves a few gradient entries slightly.
    for name, p in net.named_parameters():
        assert p.grad.abs().max() > 0, name
        assert relative_difference(ddp["grads"][name], p.grad) < 1e-3, name
    train(single, progress=False)
    torch.manual_seed(single.seed)
    init = build_model(single.model, **model_kwargs_of(single, spec)).state_dict()
    a, b = state_of(tmp_path / "ddp" / "last.pt"), state_of(tmp_path / "single" / "last.pt")
    for name in init:
        if name.endswith("weight"):
            moved = (b[name] - init[name]).norm()
            assert moved > 0 and (a[name] - b[name]).norm() < 1e-2 * moved, name


def relative_difference(a: torch.Tensor, b: torch.Tensor) -> float:
    return float((a - b).norm() / b.norm())


# ------------------------------------------------------------------------------ the CLI


def test_a_resumed_run_on_other_validation_data_starts_its_best_record_afresh(dataset, tmp_path):
    run = tmp_path / "relay"
    train(tiny_config(dataset, run, iterations=2), progress=False)
    first = torch.load(run / "resume.pt", weights_only=False)
    # Same data: the record carries over, so a worse score later cannot replace best.pt.
    train(tiny_config(dataset, run, iterations=3, val_every=3), resume=True, progress=False)
    same = torch.load(run / "resume.pt", weights_only=False)
    assert same["best_on"] == first["best_on"] and same["best"] <= first["best"]
    # Other validation windows (here: fewer of them): the old best no longer counts.
    train(
        tiny_config(dataset, run, iterations=4, val_every=4, val_windows=1),
        resume=True,
        progress=False,
    )
    other = torch.load(run / "resume.pt", weights_only=False)
    with open(run / "log.csv", newline="") as f:
        last_val = float(list(csv.DictReader(f))[-1]["val_median_rel"])
    assert other["best_on"] != first["best_on"]
    assert other["best"] == pytest.approx(last_val, rel=1e-5)


def test_cli_trains_overrides_options_and_resumes(dataset, tmp_path):
    runner = CliRunner()
    out = tmp_path / "cli"
    args = [
        "train", "--preset", "cpu", "--data", str(dataset), "--out", str(out),
        "--sensor-width", str(SIZE), "--sensor-height", str(SIZE), "--scale", "1",
        "--window-ms", "20", "--loss-start-step", "10", "--batch-size", "2",
        "--iterations", "2", "--val-every", "2", "--num-workers", "0", "--threads", "1",
        "--device", "cpu",
    ]  # fmt: skip
    result = runner.invoke(app, args, catch_exceptions=False)
    assert result.exit_code == 0, result.output
    assert "throughput:" in result.output and "bare step" in result.output
    saved = json.loads((out / "config.json").read_text())
    assert saved["preset"] == "cpu" and saved["batch_size"] == 2 and saved["scale"] == 1.0
    assert saved["train_window_ms"] == 60 and saved["train_loss_start_step"] == 45  # preset
    assert saved["max_minutes"] == 10.0
    again = runner.invoke(app, args)
    assert again.exit_code != 0 and "already holds a run" in str(again.exception)
    more = ["train", "--resume", "--out", str(out), "--iterations", "4", "--lr", "3e-5"]
    result = runner.invoke(app, more, catch_exceptions=False)
    assert result.exit_code == 0, result.output
    state = torch.load(out / "resume.pt", weights_only=False)
    assert state["step"] == 4
    # --lr on --resume takes effect (the saved optimizer state holds the first rate)
    assert saved["lr"] != 3e-5
    assert [g["lr"] for g in state["optimizer"]["param_groups"]] == [pytest.approx(3e-5)]
    assert state["scheduler"]["base_lrs"] == [pytest.approx(3e-5)]
    with (out / "log.csv").open() as f:
        assert float(list(csv.DictReader(f))[-1]["lr"]) == pytest.approx(3e-5)
    spent = ["train", "--resume", "--out", str(out), "--iterations", "6", "--max-minutes", "1e-6"]
    before = (out / "log.csv").read_text()
    refused = runner.invoke(app, spent)
    assert refused.exit_code != 0 and "counts the whole run" in str(refused.exception)
    assert (out / "log.csv").read_text() == before  # nothing half-written


@pytest.mark.parametrize("native", [False, True])
def test_cli_trains_an_ann_in_bf16(dataset, tmp_path, monkeypatch, native):
    """Warned only on a CPU without bfloat16 instructions, where autocast is slower."""
    monkeypatch.setattr(train_commands, "cpu_has_bfloat16", lambda: native)
    out = tmp_path / "amp"
    args = [
        "train", "--model", "ann6", "--amp", "bf16", "--data", str(dataset), "--out", str(out),
        "--sensor-width", str(SIZE), "--sensor-height", str(SIZE), "--window-ms", "20",
        "--loss-start-step", "10", "--batch-size", "2", "--iterations", "2", "--val-every", "2",
        "--num-workers", "0", "--threads", "1", "--device", "cpu", "--bare-steps", "1",
    ]  # fmt: skip
    result = CliRunner().invoke(app, args, catch_exceptions=False)
    assert result.exit_code == 0, result.output
    assert ("warning: --amp bf16 on a CPU" in result.output) is not native
    assert json.loads((out / "config.json").read_text())["amp"] == "bf16"
    assert training_info(load_checkpoint(out / "last.pt")[1])["amp"] == "bf16"


def interrupt_after(monkeypatch, steps: int) -> None:
    """Deliver a real SIGINT to this process right after training step ``steps``."""
    import spikegyro.train.loop as loop

    done = []

    def step(*args, **kwargs):
        loss = train_step(*args, **kwargs)
        done.append(1)
        if len(done) == steps:
            signal.raise_signal(signal.SIGINT)
        return loss

    monkeypatch.setattr(loop, "train_step", step)


def test_ctrl_c_stops_after_the_step_with_a_checkpoint_to_resume_from(
    dataset, tmp_path, monkeypatch
):
    handler = signal.getsignal(signal.SIGINT)
    interrupt_after(monkeypatch, 2)
    result = train(tiny_config(dataset, tmp_path, iterations=6, val_every=100), progress=False)
    assert (result.steps, result.interrupted, result.stopped_early) == (2, True, True)
    assert signal.getsignal(signal.SIGINT) is handler
    assert torch.load(tmp_path / "resume.pt", weights_only=False)["step"] == 2
    assert "val_median_rel" in result.val  # validated before stopping, like the time budget
    monkeypatch.undo()
    resumed = train(resume_config(tmp_path), resume=True, progress=False)
    assert (resumed.steps, resumed.interrupted) == (6, False)


def test_cli_exits_130_after_ctrl_c_and_says_how_to_resume(dataset, tmp_path, monkeypatch):
    interrupt_after(monkeypatch, 1)
    args = ["train", "--data", str(dataset), "--out", str(tmp_path / "run"), "--sensor-width",
            str(SIZE), "--sensor-height", str(SIZE), "--window-ms", "20", "--loss-start-step",
            "10", "--batch-size", "2", "--iterations", "5", "--num-workers", "0", "--device",
            "cpu", "--bare-steps", "0"]  # fmt: skip
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 130, result.output
    assert "interrupted: 1 steps" in result.output
    assert "--resume" in result.output
    assert (tmp_path / "run" / "last.pt").exists()


def test_frozen_layers_keep_their_init_weights_while_the_rest_learn(dataset, tmp_path):
    train(tiny_config(dataset, tmp_path / "a", iterations=2), progress=False)
    init = tmp_path / "a" / "last.pt"
    train(tiny_config(dataset, tmp_path / "b", init=str(init), freeze=4), progress=False)
    start, tuned = state_of(init), state_of(tmp_path / "b" / "last.pt")
    weights = [name for name in start if name.endswith(".weight")]
    assert len(weights) == 6
    for name in weights:
        same = torch.equal(start[name], tuned[name])
        assert same == name.startswith(("conv1.", "conv2.", "conv3.", "conv4.")), name
    assert json.loads((tmp_path / "b" / "config.json").read_text())["freeze"] == 4
    with pytest.raises(InputError, match="trained with freeze = 4, not 3"):
        resume_config(tmp_path / "b", {"freeze": 3, "iterations": 9})
    assert resume_config(tmp_path / "b", {"freeze": 4}).freeze == 4


def test_config_errors_are_user_errors(tmp_path):
    with pytest.raises(InputError, match="--model"):
        resolve_config("paper", {"data": "x", "model": "lenet"})
    with pytest.raises(InputError, match="spikes"):
        resolve_config("paper", {"data": "x", "model": "ann6", "input": "spikes"})
    with pytest.raises(InputError, match="--preset"):
        resolve_config("gpu", {"data": "x"})
    with pytest.raises(InputError, match="--amp fp8"):
        resolve_config("paper", {"data": "x", "model": "ann6", "amp": "fp8"})
    with pytest.raises(InputError, match="float32"):
        resolve_config("paper", {"data": "x", "model": "snn6", "amp": "bf16"})
    with pytest.raises(InputError, match="--online"):
        resolve_config("paper", {})
    with pytest.raises(InputError, match="batch norms"):
        resolve_config("paper", {"data": "x", "model": "ann6", "freeze": 2})
    with pytest.raises(InputError, match="--freeze 6: SNN-6 has 5"):
        resolve_config("paper", {"data": "x", "freeze": 6})


def test_online_mode_simulates_fresh_sequences_in_workers(tmp_path):
    sim = {"camera": {"width": SIZE, "height": SIZE, "fx": 56.0, "fy": 56.0, "cx": 31.5,
                      "cy": 31.5}}  # fmt: skip
    config = resolve_config(
        "paper",
        dict(
            online=True, out=str(tmp_path), sensor=(SIZE, SIZE), sim=sim, window_ms=20,
            loss_start_step=10, batch_size=2, iterations=2, val_every=2, val_sequences=2,
            num_workers=1, device="cpu", threads=1,
        ),
    )  # fmt: skip
    spec = input_spec_of(config)
    samples = training_samples(config, spec)
    first, second = samples.window(0), samples.window(1)
    assert first.source == "online:0" and second.source == "online:1"
    assert not np.allclose(first.omega, second.omega)  # a new random motion per sample
    np.testing.assert_array_equal(samples.window(0).events.t, first.events.t)  # reproducible
    result = train(config, progress=False)
    assert result.steps == 2 and np.isfinite(result.val["val_loss"])
    assert not any(tmp_path.glob("**/*.h5"))


def test_cli_stops_on_a_failing_sample_in_one_line_keeping_the_checkpoint(
    dataset, tmp_path, monkeypatch, capfd
):
    """A window that a data worker cannot make (here: every sample from step 3 on) ends the run
    with one line: the cause, the checkpoint of step 2 kept, and the command that continues."""
    from spikegyro.cli import run
    from spikegyro.train.data import TrainingSamples

    made = TrainingSamples.window

    def window(self, index):
        if index >= 4:  # batch 2: the samples of steps 3 and on
            raise ValueError("unreadable\nwindow")
        return made(self, index)

    monkeypatch.setattr(TrainingSamples, "window", window)  # the forked worker inherits it
    out = tmp_path / "run"
    args = ["train", "--model", "ann6", "--data", str(dataset), "--out", str(out),
            "--sensor-width", str(SIZE), "--sensor-height", str(SIZE), "--window-ms", "20",
            "--loss-start-step", "10", "--batch-size", "2", "--iterations", "6", "--val-every",
            "2", "--num-workers", "1", "--device", "cpu", "--bare-steps", "0"]  # fmt: skip
    capfd.readouterr()
    assert run(args) == 1
    err = [line for line in capfd.readouterr().err.splitlines() if line.strip()]
    assert [line for line in err if line.startswith("precision:")] == err[:1]  # said at start
    err = err[1:]
    assert len(err) == 1, err
    assert err[0].startswith("error: training stopped, a data worker failed: training sample 4 ")
    assert "ValueError: unreadable window" in err[0]
    assert f"{out / 'last.pt'} (step 2) is kept" in err[0]
    assert err[0].endswith(f"continue with: spikegyro train --resume --out {out}")
    assert load_checkpoint(out / "last.pt")[1]["extra"]["step"] == 2
