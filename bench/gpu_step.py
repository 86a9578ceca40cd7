"""SNN-6 training step on a GPU: spikegyro's reference and fused steps against slayerPytorch's.

One step = forward + backward + Adam update of SNN-6 on a batch of random input spikes (1 %
density, like real 100 ms windows at 240x180) already on the device, with the paper's loss
(mean Euclidean error from step 50 of 100). Variants, all in one run and on the same input and
initial weights:

- ``reference``: spikegyro's torch code (``SPIKEGYRO_TRITON=0``);
- ``fused``: the Triton spike kernels (:mod:`spikegyro.snn.triton_kernels`);
- ``slayer``: slayerPytorch's CUDA SNN-6, the implementation the paper trained with, built from a
  checkout of its repository (``--slayer DIR``): the bench copies it to ``--slayer-build``,
  replaces three C++ APIs that PyTorch removed, compiles ``slayerKernels.cu`` with
  ``torch.utils.cpp_extension.load`` and loads the same weights;
- optional: ``--compile`` (torch.compile of the fused model), ``--cuda-graph`` (the whole fused
  step captured in one CUDA graph), ``--tf32`` (fused with TF32 matmuls and convolutions) and
  ``--strict-fp32`` (fused with TF32 off everywhere; by default PyTorch lets cuDNN use TF32).

For each variant: median ms/step over ``--repeats`` after ``--warmup`` steps, samples/s, peak
GPU memory of a step, the ratio to slayer's and the reference's time, and how far its first
output (same weights, same input) is from the reference's: max |Δω| relative to max |ω|.

With ``--data DIR`` (a simulated dataset of the same sensor) it also runs ``spikegyro train``
for ``--data-steps`` steps on each data path (dense tensors from the workers, event lists binned
on the device) and prints the run's samples/s against the bare step measured in the same run.

    python bench/gpu_step.py --slayer anchors/slayerpytorch --data /tmp/data --cuda-graph
    python bench/gpu_step.py --device cpu --tiny        # executes everything small on a CPU
"""

from __future__ import annotations

import argparse
import contextlib
import copy
import importlib.util
import json
import math
import os
import shutil
import statistics
import sys
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path

PATCHES = {"x.type().is_cuda()": "x.is_cuda()", ".data<float>()": ".data_ptr<float>()",
           "AT_ASSERTM": "TORCH_CHECK"}  # fmt: skip
"""The three APIs PyTorch removed since slayerPytorch was written, and their replacements."""


def parse() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default=None, help="cuda (default when present) or cpu")
    parser.add_argument("--tiny", action="store_true", help="64x64, T=12, batch 1: a smoke run")
    parser.add_argument("--batch", type=int, default=16)
    parser.add_argument("--width", type=int, default=240)
    parser.add_argument("--height", type=int, default=180)
    parser.add_argument("--steps", type=int, default=100, help="time steps T (1 ms each)")
    parser.add_argument("--density", type=float, default=0.01)
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--warmup", type=int, default=3)
    parser.add_argument("--slayer", type=Path, help="copy of the slayerpytorch anchor")
    parser.add_argument(
        "--slayer-build",
        type=Path,
        default=Path(".slayer-build"),
        help="scratch folder for the patched copy and its build (git-ignored)",
    )
    parser.add_argument("--compile", action="store_true", help="add torch.compile (fused)")
    parser.add_argument("--cuda-graph", action="store_true", help="add a CUDA-graphed fused step")
    parser.add_argument("--tf32", action="store_true", help="add fused with TF32 everywhere")
    parser.add_argument("--strict-fp32", action="store_true", help="add fused with TF32 off")
    parser.add_argument("--data", type=Path, help="dataset for the data-path comparison")
    parser.add_argument("--data-steps", type=int, default=150)
    parser.add_argument("--workers", type=int, default=12)
    parser.add_argument("--json", type=Path, help="also write the results here")
    args = parser.parse_args()
    if args.tiny:
        args.width = args.height = 64
        args.batch, args.steps, args.repeats, args.warmup = 1, 12, 1, 0
        args.density, args.data_steps, args.workers = 0.1, 3, 0
    return args


# ------------------------------------------------------------------------------- variants


@contextlib.contextmanager
def settings(triton: bool, tf32: bool | None = None) -> Iterator[None]:
    """Run with the Triton kernels on or off and (if given) TF32 on or off."""
    import torch

    saved = (os.environ.get("SPIKEGYRO_TRITON"), torch.backends.cuda.matmul.allow_tf32,
             torch.backends.cudnn.allow_tf32)  # fmt: skip
    os.environ["SPIKEGYRO_TRITON"] = "1" if triton else "0"
    if tf32 is not None:
        torch.backends.cuda.matmul.allow_tf32 = torch.backends.cudnn.allow_tf32 = tf32
    try:
        yield
    finally:
        if saved[0] is None:
            del os.environ["SPIKEGYRO_TRITON"]
        else:
            os.environ["SPIKEGYRO_TRITON"] = saved[0]
        torch.backends.cuda.matmul.allow_tf32, torch.backends.cudnn.allow_tf32 = saved[1:]


def build_slayer(anchor: Path, build: Path):
    """slayerPytorch's ``slayer`` module, compiled from a patched scratch copy of ``anchor``."""
    from torch.utils.cpp_extension import load

    source = build / "slayerpytorch"
    if source.exists():
        shutil.rmtree(source)
    shutil.copytree(anchor, source)
    cuda = source / "src" / "cuda"
    for path in cuda.iterdir():
        text = path.read_text()
        for old, new in PATCHES.items():
            text = text.replace(old, new)
        path.write_text(text)
    (build / "ext").mkdir(parents=True, exist_ok=True)
    sys.modules["slayerCuda"] = load(
        name="slayerCuda", sources=[str(cuda / "slayerKernels.cu")],
        build_directory=str(build / "ext"), verbose=False,
    )  # fmt: skip
    spec = importlib.util.spec_from_file_location("slayer_anchor", source / "src" / "slayer.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def slayer_snn6(slayer, ours, steps: int):
    """The official SNN-6 in slayer's terms (the anchor README), with ``ours``'s weights."""
    import torch
    from torch import nn

    from spikegyro.models.snn6 import READOUT, SNN6_LAYERS

    simulation = {"Ts": 1.0, "tSample": steps}

    def neuron(p, theta, tau_r):
        return {"type": "SRMALPHA", "theta": theta, "tauSr": p.tau_s, "tauRef": tau_r,
                "scaleRef": 2, "tauRho": 0.3, "scaleRho": p.scale_rho}  # fmt: skip

    class SlayerSNN6(nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.layers = nn.ModuleList()
            self.convs = nn.ModuleList()
            cin = 2
            for spec, mine in zip(SNN6_LAYERS, ours.convs, strict=True):
                p = spec.params
                layer = slayer.spikeLayer(neuron(p, p.theta, p.tau_r), simulation)
                conv = layer.conv(cin, spec.out_channels, 3, spec.stride, padding=0,
                                  weightScale=1)  # fmt: skip
                conv.weight.data.copy_(mine.weight.detach()[..., None])
                self.layers.append(layer)
                self.convs.append(conv)
                cin = spec.out_channels
            # the readout never spikes; θ and τr only shape an unused refractory kernel
            self.out = slayer.spikeLayer(neuron(READOUT, 1.0, 1.0), simulation)
            self.fc = self.out.dense(cin, 3, weightScale=1)
            self.fc.weight.data.copy_(ours.fc.weight.detach()[:, :, None, None, None])

        def forward(self, x: torch.Tensor) -> torch.Tensor:
            s = x
            for layer, conv in zip(self.layers, self.convs, strict=True):
                s = layer.spike(conv(layer.psp(s)))
            mean = torch.mean(s, dim=(2, 3), keepdim=True)
            return self.out.psp(self.fc(mean)).flatten(1, 3)

    return SlayerSNN6().float()


def make_variants(args, device) -> dict[str, tuple[Callable, Callable]]:
    """name -> (build(model) -> model to step, context manager factory)."""
    import torch

    variants = {
        "reference": (lambda m: m, lambda: settings(triton=False)),
        "fused": (lambda m: m, lambda: settings(triton=True)),
    }
    if args.slayer:
        slayer = build_slayer(args.slayer.resolve(), args.slayer_build.resolve())
        variants["slayer"] = (lambda m: slayer_snn6(slayer, m, args.steps).to(device),
                              lambda: settings(triton=False))  # fmt: skip
    if args.compile:
        variants["fused+compile"] = (torch.compile, lambda: settings(triton=True))
    if args.cuda_graph:
        variants["fused+cuda-graph"] = (lambda m: m, lambda: settings(triton=True))
    if args.tf32:
        variants["fused+tf32"] = (lambda m: m, lambda: settings(triton=True, tf32=True))
    if args.strict_fp32:
        variants["fused+strict-fp32"] = (lambda m: m, lambda: settings(triton=True, tf32=False))
    return variants


def graphed(step: Callable[[], object], device) -> Callable[[], None]:
    """``step`` captured in a CUDA graph (warmed up on a side stream first), replayed."""
    import torch

    stream = torch.cuda.Stream(device)
    stream.wait_stream(torch.cuda.current_stream(device))
    with torch.cuda.stream(stream):
        for _ in range(3):
            step()
    torch.cuda.current_stream(device).wait_stream(stream)
    graph = torch.cuda.CUDAGraph()
    with torch.cuda.graph(graph):
        step()
    return graph.replay


def measure(name, build, context, base_model, x, y, args, device, reference_out) -> dict:
    """Time one variant's training step; its first output against the reference's."""
    import torch

    from spikegyro.train.throughput import timed_steps, train_step

    model = build(copy.deepcopy(base_model))
    with context():
        with torch.no_grad():
            out = model(x)
        optimizer = torch.optim.Adam(model.parameters(), lr=1e-4,
                                     capturable=name.endswith("cuda-graph"))  # fmt: skip

        def step():
            return train_step(model, optimizer, x, y, args.steps // 2)

        run = graphed(step, device) if name.endswith("cuda-graph") else step
        times, peak = timed_steps(run, device, warmup=args.warmup, repeats=args.repeats)
    peak = math.nan if peak is None else peak
    ms = 1000 * statistics.median(times)
    # The reference itself has nothing to be compared with: None, not a vacuous 0.
    diff = None
    if reference_out is not None:
        scale = float(reference_out.abs().max()) or 1.0
        diff = float((out - reference_out).abs().max()) / scale
    return {"variant": name, "ms_per_step": ms, "samples_per_s": args.batch / ms * 1000,
            "peak_gib": peak, "out_rel_diff": diff, "out_abs_max": float(out.abs().max()),
            "_out": out}  # fmt: skip


def step_table(rows: list[dict]) -> list[str]:
    by = {r["variant"]: r for r in rows if "ms_per_step" in r}
    lines = ["| variant | ms/step | samples/s | peak GPU memory (GiB) | slayer time / time | "
             "reference time / time | max abs Δω / max abs ω vs reference |",
             "|---|---:|---:|---:|---:|---:|---:|"]  # fmt: skip
    for r in rows:
        if "error" in r:
            lines.append(f"| {r['variant']} | failed: {r['error']} | | | | | |")
            continue
        vs_slayer = by["slayer"]["ms_per_step"] / r["ms_per_step"] if "slayer" in by else math.nan
        vs_ref = (
            by["reference"]["ms_per_step"] / r["ms_per_step"] if "reference" in by else math.nan
        )
        lines.append(
            f"| {r['variant']} | {r['ms_per_step']:.1f} | {r['samples_per_s']:.1f} | "
            f"{r['peak_gib']:.2f} | {vs_slayer:.2f}x | {vs_ref:.2f}x | "
            + ("-" if r["out_rel_diff"] is None else f"{r['out_rel_diff']:.2e}")
            + " |"
        )
    return lines


# ------------------------------------------------------------------------------ data path


def data_paths(args, device) -> list[dict]:
    """``spikegyro train`` on each data path: the run's samples/s against its bare step."""
    from spikegyro.train.loop import train
    from spikegyro.train.presets import resolve_config

    rows = []
    for path in ("dense", "events"):
        with tempfile.TemporaryDirectory() as out:
            config = resolve_config("paper", dict(
                data=str(args.data), out=out, sensor=(args.width, args.height),
                window_ms=args.steps, loss_start_step=args.steps // 2, batch_size=args.batch,
                iterations=args.data_steps, val_every=args.data_steps, val_windows=args.batch,
                log_every=max(1, args.data_steps // 5), num_workers=args.workers,
                device=str(device), data_path=path, bare_steps=max(3, args.repeats // 2),
            ))  # fmt: skip
            result = train(config, progress=False)
        rows.append({"data_path": path, "run_samples_per_s": result.samples_per_s,
                     "bare_samples_per_s": result.bare.samples_per_s,
                     "bare_ms_per_step": result.bare.ms_per_step,
                     "workers": args.workers, "steps": result.steps})  # fmt: skip
    return rows


def data_table(rows: list[dict]) -> list[str]:
    lines = ["| data path | run samples/s | bare step samples/s (ms/step) | run / bare |",
             "|---|---:|---:|---:|"]  # fmt: skip
    for r in rows:
        ratio = r["run_samples_per_s"] / r["bare_samples_per_s"]
        lines.append(
            f"| {r['data_path']} | {r['run_samples_per_s']:.1f} | {r['bare_samples_per_s']:.1f} "
            f"({r['bare_ms_per_step']:.1f}) | {ratio:.0%} |"
        )
    return lines


# ------------------------------------------------------------------------------------ main


def main() -> None:
    args = parse()
    import torch

    device = torch.device(args.device or ("cuda" if torch.cuda.is_available() else "cpu"))
    if device.type == "cpu":
        # the fused variant then runs Triton's interpreter (set before Triton is imported)
        os.environ["TRITON_INTERPRET"] = "1"
        torch.set_num_threads(min(2, torch.get_num_threads()))
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from spikegyro.models.snn6 import SNN6

    torch.manual_seed(0)
    base = SNN6().to(device)
    x = (torch.rand(args.batch, 2, args.height, args.width, args.steps, device=device)
         < args.density).float()  # fmt: skip
    y = torch.randn(args.batch, 3, args.steps, device=device)
    variants = make_variants(args, device)
    if importlib.util.find_spec("triton") is None:
        print("triton is not installed (pip install spikegyro[gpu]): fused variants skipped")
        variants = {k: v for k, v in variants.items() if not k.startswith("fused")}
    rows, reference_out = [], None
    for name, (build, context) in variants.items():
        if name.endswith("cuda-graph") and device.type != "cuda":
            continue
        try:
            row = measure(name, build, context, base, x, y, args, device, reference_out)
        except Exception as exc:  # a failing option must not hide the other measurements
            rows.append({"variant": name, "error": f"{type(exc).__name__}: {exc}"[:200]})
            continue
        if name == "reference":
            reference_out = row["_out"]
        rows.append(row)
        print(f"  {name}: {row['ms_per_step']:.1f} ms/step", file=sys.stderr)
    for row in rows:
        row.pop("_out", None)
    gpu = torch.cuda.get_device_name(device) if device.type == "cuda" else "CPU"
    print(f"SNN-6 training step (forward + backward + Adam), batch {args.batch}, "
          f"{args.width}x{args.height}, T = {args.steps}, input density {args.density:.0%}, "
          f"torch {torch.__version__}, {gpu}, median of {args.repeats} steps after "
          f"{args.warmup} warm-up; cuDNN TF32 {'on' if torch.backends.cudnn.allow_tf32 else 'off'}"
          " unless the variant says otherwise")  # fmt: skip
    print("\n".join(step_table(rows)))
    results = {"device": gpu, "steps": rows}
    if args.data:
        with settings(triton=device.type == "cuda"):  # no interpreter for whole runs on a CPU
            results["data_paths"] = data_paths(args, device)
        print(f"\n`spikegyro train`, {args.data_steps} steps, batch {args.batch}, "
              f"{args.workers} workers: the run against the bare step of the same run")  # fmt: skip
        print("\n".join(data_table(results["data_paths"])))
    if args.json:
        args.json.write_text(json.dumps(results, indent=2) + "\n")


if __name__ == "__main__":
    main()
