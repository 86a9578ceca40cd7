"""NIR export/import of SNN-6: the neuron mapping against NIR's own equations, file round trips."""

from __future__ import annotations

import math
import sys

import numpy as np
import pytest
import torch

from spikegyro.cli import main
from spikegyro.errors import InputError
from spikegyro.models.registry import build_model, save_checkpoint
from spikegyro.models.snn6 import READOUT, SNN6, SNN6_LAYERS
from spikegyro.snn.kernels import srm_kernel

nir = pytest.importorskip("nir")

from spikegyro.models.nir import export_nir, from_nir, read_nir, to_nir  # noqa: E402

H, W = 70, 80  # just above SNN-6's 63 px minimum: a 1x2 layer-5 map


@pytest.fixture
def checkpoint(tmp_path):
    torch.manual_seed(3)
    path = tmp_path / "snn6.pt"
    spec = {"representation": "spikes", "sensor": [2 * W, 2 * H], "scale": 0.5, "window_ms": 40}
    save_checkpoint(path, build_model("snn6"), name="snn6", model_kwargs={}, input_spec=spec)
    return path


def _impulse_response(node, t_end_s: float, dt_s: float = 1e-6) -> np.ndarray:
    """v(t) of NIR's CubaLI(F) equations (threshold ignored) for one unit-area input impulse at
    t = 0, integrated with exact exponential steps of ``dt_s``, sampled every 1 ms."""
    tau_syn, tau_mem = float(node.tau_syn.flat[0]), float(node.tau_mem.flat[0])
    r, w_in = float(node.r.flat[0]), float(node.w_in.flat[0])
    current, v, samples = w_in / tau_syn, 0.0, [0.0]
    per_ms = round(1e-3 / dt_s)
    for step in range(1, round(t_end_s / dt_s) + 1):
        # midpoint current over the step drives v (second-order accurate)
        mid = current * math.exp(-dt_s / (2 * tau_syn))
        v += (r * mid - v) * (1 - math.exp(-dt_s / tau_mem))
        current *= math.exp(-dt_s / tau_syn)
        if step % per_ms == 0:
            samples.append(v)
    return np.array(samples)


@pytest.mark.parametrize("layer", [0, 2, "readout"])
def test_exported_neuron_has_snn6s_psp_kernel_under_nirs_equations(layer):
    graph = to_nir(SNN6(), H, W)
    node = graph.nodes["readout" if layer == "readout" else f"lif{layer + 1}"]
    tau_ms = READOUT.tau_s if layer == "readout" else SNN6_LAYERS[layer].params.tau_s
    kernel = srm_kernel(tau_ms).double().numpy()
    response = _impulse_response(node, (len(kernel) - 1) * 1e-3)
    np.testing.assert_allclose(response, kernel, atol=2e-6)
    if layer != "readout":
        assert float(node.v_threshold.flat[0]) == pytest.approx(SNN6_LAYERS[layer].params.theta)


def test_file_round_trip_gives_identical_weights_and_outputs(checkpoint, tmp_path):
    path = export_nir(checkpoint, tmp_path / "snn6.nir")
    model, (height, width) = read_nir(path)
    assert (height, width) == (H, W)  # the checkpoint's sensor x scale
    original = build_model("snn6")
    original.load_state_dict(torch.load(checkpoint, weights_only=False)["state_dict"])
    original.eval()
    for (name, a), (_, b) in zip(
        original.state_dict().items(), model.state_dict().items(), strict=True
    ):
        assert torch.equal(a, b), name
    x = (torch.rand(2, 2, H, W, 40, generator=torch.Generator().manual_seed(0)) < 0.05).float()
    with torch.no_grad():
        expected, spikes = original.forward_with_spikes(x)
        got = model(x)
    assert spikes[-1].sum() > 0  # layer 5 fires, so the outputs are not trivially zero
    assert torch.equal(expected, got)
    assert not list(tmp_path.glob(".snn6.nir*"))  # written atomically


def test_graph_structure_and_refractory_metadata():
    graph = to_nir(SNN6(), H, W)
    kinds = [type(graph.nodes[a]).__name__ for a, _ in graph.edges] + ["Output"]
    assert kinds == ["Input", *["Conv2d", "CubaLIF"] * 5, "AvgPool2d", "Flatten", "Linear",
                     "CubaLI", "Output"]  # fmt: skip
    assert list(graph.nodes["gasp"].kernel_size) == [1, 2]
    meta = graph.nodes["lif4"].metadata["spikegyro"]
    assert meta["tau_r_ms"] == SNN6_LAYERS[3].params.tau_r


def test_foreign_graph_without_metadata_takes_snn6s_refractory():
    graph = to_nir(SNN6(), H, W)
    for index in range(1, 6):
        graph.nodes[f"lif{index}"].metadata = {}
    model, _ = from_nir(graph)
    assert model.conv4.params.tau_r == SNN6_LAYERS[3].params.tau_r


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda g: setattr(g.nodes["lif3"], "v_threshold", g.nodes["lif3"].v_threshold * 2),
         "lif3.*θ"),
        (lambda g: setattr(g.nodes["lif2"], "tau_mem", g.nodes["lif2"].tau_mem * 2), "τ_mem"),
        (lambda g: setattr(g.nodes["lif1"], "r", g.nodes["lif1"].r * 3), "R·w_in"),
        (lambda g: setattr(g.nodes["conv2"], "bias", g.nodes["conv2"].bias + 1), "no bias"),
        (lambda g: g.nodes.pop("fc"), "Linear node 'fc'"),
    ],
)  # fmt: skip
def test_import_refuses_what_snn6_cannot_hold(edit, message):
    graph = to_nir(SNN6(), H, W)
    edit(graph)
    with pytest.raises(InputError, match=message):
        from_nir(graph)


def test_missing_extra_is_named(monkeypatch, checkpoint, tmp_path):
    monkeypatch.setitem(sys.modules, "nir", None)
    with pytest.raises(InputError, match=r"spikegyro\[nir\]"):
        export_nir(checkpoint, tmp_path / "x.nir")


def test_cli_exports_and_refuses_bad_input(checkpoint, tmp_path, monkeypatch, capsys):
    out = tmp_path / "snn6.nir"
    monkeypatch.setattr(sys, "argv", ["spikegyro", "export-nir", str(checkpoint), str(out)])
    main()  # returns normally on success
    assert read_nir(out)[1] == (H, W)
    ann = tmp_path / "ann.pt"
    spec = {"representation": "voxel", "sensor": [W, H], "output": "window_mean"}
    save_checkpoint(ann, build_model("ann6", in_channels=5), name="ann6",
                    model_kwargs={"in_channels": 5}, input_spec=spec)  # fmt: skip
    (tmp_path / "junk.nir").write_text("not hdf5")
    for argv, text in (
        (["export-nir", str(ann), str(tmp_path / "a.nir")], "only SNN-6"),
        (["export-nir", str(tmp_path / "none.pt"), str(out)], "none.pt: no such checkpoint file"),
    ):
        monkeypatch.setattr(sys, "argv", ["spikegyro", *argv])
        with pytest.raises(SystemExit) as failed:
            main()
        assert failed.value.code == 2 and text in capsys.readouterr().err
    assert not (tmp_path / "a.nir").exists()
    with pytest.raises(InputError, match=r"junk\.nir: not a readable NIR file"):
        read_nir(tmp_path / "junk.nir")
