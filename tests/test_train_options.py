"""`spikegyro train`'s options and TrainConfig's fields: an option per field, each reaching it."""

from __future__ import annotations

import inspect
import math
from pathlib import Path

import pytest
from typer.testing import CliRunner

import spikegyro.train.commands as commands
from spikegyro.cli import app, run
from spikegyro.train.loop import TrainResult
from spikegyro.train.presets import TrainConfig, field_names


def test_every_config_field_is_given_in_exactly_one_place():
    options, own = set(commands.OPTION_HELP), set(commands.COMMAND_FIELDS)
    assert not options & own, f"fields with two options: {options & own}"
    assert options | own == set(field_names()), (
        f"fields with no option (add them to OPTION_HELP): {set(field_names()) - options - own}; "
        f"options of no field: {(options | own) - set(field_names())}"
    )


def test_every_option_of_train_sets_a_config_field():
    parameters = set(inspect.signature(commands.train_command).parameters)
    own = {name for names in commands.COMMAND_FIELDS.values() for name in names}
    assert parameters == set(commands.OPTION_HELP) | own


@pytest.fixture
def given(monkeypatch) -> dict[str, TrainConfig]:
    """Run ``train`` without training: the resolved configuration lands under "config"."""
    seen: dict[str, TrainConfig] = {}

    def fake_train(config: TrainConfig, *, resume: bool) -> TrainResult:
        seen["config"] = config
        return TrainResult(Path(config.out), 0, 0.0, math.nan, math.inf)

    monkeypatch.setattr(commands, "train", fake_train)
    return seen


def test_options_reach_their_fields_with_the_fields_types(given, tmp_path):
    args = [
        "train", "--data", str(tmp_path), "--out", str(tmp_path / "run"), "--online",
        "--model-kwargs", '{"tau_scale": 2.0}', "--sim", '{"seed_offset": 3}', "--lr", "0.5",
        "--freeze", "2", "--sensor-width", "64", "--sensor-height", "48", "--no-tensorboard",
        "--device", "cpu", "--compute", "dense",
    ]  # fmt: skip
    result = CliRunner().invoke(app, args, catch_exceptions=False)
    assert result.exit_code == 0, result.output
    config = given["config"]
    assert config.data == str(tmp_path) and config.out == str(tmp_path / "run")
    assert config.online is True and config.tensorboard is False
    assert config.model_kwargs == {"tau_scale": 2.0} and config.sim == {"seed_offset": 3}
    assert (config.lr, config.freeze, config.sensor) == (0.5, 2, (64, 48))
    assert config.preset == "paper" and config.batch_size == 16  # untouched: the preset's


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--model-kwargs", "[1]"], "--model-kwargs '[1]': expected a JSON object"),
        (["--sim", "{"], "--sim '{': not valid JSON"),
        (["--sensor-width", "64"], "--sensor-width and --sensor-height go together"),
        (["--resume"], "--resume needs --out"),
    ],
)
def test_bad_options_are_one_line_errors(given, tmp_path, capsys, args, message):
    assert run(["train", "--data", str(tmp_path), *args]) == 2
    assert message in capsys.readouterr().err
    assert "config" not in given


@pytest.mark.parametrize(
    ("amp", "representation", "device", "native", "resolved"),
    [
        ("auto", "voxel", "cpu", True, "bf16"),
        ("auto", "frames", "cpu", False, "off"),
        ("auto", "voxel", "cuda", True, "off"),
        ("auto", "spikes", "cpu", True, "off"),
        ("bf16", "voxel", "cpu", False, "bf16"),
        ("off", "voxel", "cpu", True, "off"),
    ],
)
def test_amp_auto_is_bfloat16_for_the_anns_on_a_cpu_that_computes_in_it(
    monkeypatch, amp, representation, device, native, resolved
):
    import torch

    from spikegyro.train import throughput

    monkeypatch.setattr(throughput, "cpu_has_bfloat16", lambda: native)
    monkeypatch.setattr(commands, "cpu_has_bfloat16", lambda: native)
    assert throughput.resolve_amp(amp, representation, torch.device(device)) == resolved
    if representation != "spikes":
        line = commands.precision_line(amp, torch.device(device))
        assert "\n" not in line
        if amp == "bf16" and not native:
            assert line.startswith("warning: --amp bf16 on a CPU without bfloat16 instructions")
        else:
            assert line.startswith(f"precision: {commands.PRECISION[resolved]}")


def test_amp_is_auto_by_default_and_bf16_is_refused_for_the_snn():
    assert TrainConfig(data="d").amp == "auto"
    assert TrainConfig(data="d", model="ann6", input="voxel").amp == "auto"
    with pytest.raises(Exception, match="mixed precision is for the ANNs"):
        TrainConfig(data="d", amp="bf16")
