"""ANN baselines: shapes, parameter counts from hand formulas, trainability, checkpoints."""

from __future__ import annotations

import itertools

import pytest
import torch

from spikegyro.models.ann6 import ANN6
from spikegyro.models.registry import build_model, load_checkpoint, save_checkpoint
from spikegyro.models.resnet import ResNet50

SENSOR_HW = (180, 240)


def n_params(model: torch.nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())


def resnet50_param_formula(in_channels: int, num_outputs: int) -> int:
    """Parameter count of a bottleneck ResNet-50 written out from the paper's Table 1.

    conv k x k from a to b channels: a*b*k*k weights; batch norm over c channels: 2c.
    """
    total = in_channels * 64 * 7 * 7 + 2 * 64  # stem conv + BN
    channels = 64
    for width, blocks in zip((64, 128, 256, 512), (3, 4, 6, 3), strict=True):
        for b in range(blocks):
            total += channels * width + 2 * width  # 1x1 reduce + BN
            total += width * width * 9 + 2 * width  # 3x3 + BN
            total += width * 4 * width + 2 * 4 * width  # 1x1 expand + BN
            if b == 0:  # projection shortcut + BN
                total += channels * 4 * width + 2 * 4 * width
            channels = 4 * width
    return total + 2048 * num_outputs + num_outputs


def test_resnet50_imagenet_layout_has_the_published_parameter_count():
    assert resnet50_param_formula(3, 1000) == 25_557_032  # the formula itself is right
    assert n_params(ResNet50(in_channels=3, num_outputs=1000)) == 25_557_032


@pytest.mark.parametrize("in_channels", [2, 5, 15])
def test_resnet50_parameter_count_for_event_inputs(in_channels):
    assert n_params(ResNet50(in_channels=in_channels, num_outputs=3)) == resnet50_param_formula(
        in_channels, 3
    )


def test_ann6_parameter_count_matches_hand_formula():
    widths = (5, 16, 32, 64, 128, 256)
    convs = sum(9 * a * b + 2 * b for a, b in itertools.pairwise(widths))  # conv + BN
    assert n_params(ANN6(in_channels=5)) == convs + 256 * 3 + 3
    plain = sum(9 * a * b + b for a, b in itertools.pairwise(widths))  # conv + bias
    assert n_params(ANN6(in_channels=5, batch_norm=False)) == plain + 256 * 3 + 3


def test_ann6_feature_map_follows_unpadded_strided_convs():
    h, w = SENSOR_HW
    for stride in (2, 2, 2, 2, 1):
        h, w = (h - 3) // stride + 1, (w - 3) // stride + 1
    assert (h, w) == (8, 12)
    feats = ANN6(in_channels=2).features(torch.zeros(1, 2, *SENSOR_HW))
    assert feats.shape == (1, 256, h, w)


@pytest.mark.parametrize(
    ("name", "in_channels"),
    [("ann6", 5), ("ann6", 2), ("resnet50", 2), ("resnet50", 5)],
    ids=["ann6-voxel", "ann6-frames", "resnet50-frames", "resnet50-voxel"],
)
def test_full_sensor_window_gives_one_omega_per_sample(name, in_channels):
    model = build_model(name, in_channels=in_channels, num_outputs=3).eval()
    with torch.no_grad():
        out = model(torch.randn(2, in_channels, *SENSOR_HW))
    assert out.shape == (2, 3)
    assert torch.isfinite(out).all()


@pytest.mark.parametrize(
    ("name", "hw", "steps"),
    [("ann6", (64, 64), 8), ("resnet50", (32, 32), 5)],
)
def test_a_few_adam_steps_reduce_the_loss_on_a_fixed_batch(name, hw, steps):
    torch.manual_seed(0)
    model = build_model(name, in_channels=5).train()
    x = torch.randn(4, 5, *hw)
    target = torch.randn(4, 3) * 2.0  # rad/s
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)

    def loss_now() -> torch.Tensor:
        return (model(x) - target).norm(dim=1).mean()

    initial = loss_now().item()
    for _ in range(steps):
        opt.zero_grad()
        loss = loss_now()
        loss.backward()
        opt.step()
    assert loss_now().item() < 0.5 * initial


@pytest.mark.parametrize(("name", "kwargs"), [("ann6", {"batch_norm": True}), ("resnet50", {})])
def test_checkpoint_round_trip_rebuilds_the_same_function(tmp_path, name, kwargs):
    model_kwargs = {"in_channels": 2, "num_outputs": 3, **kwargs}
    model = build_model(name, **model_kwargs).eval()
    x = torch.randn(1, 2, 64, 80)
    path = save_checkpoint(
        tmp_path / "m.pt",
        model,
        name=name,
        model_kwargs=model_kwargs,
        input_spec={"representation": "frames", "output": "window_mean", "window_ms": 20},
    )
    loaded, payload = load_checkpoint(path)
    assert isinstance(loaded, type(model))
    assert payload["input"]["output"] == "window_mean"
    with torch.no_grad():
        torch.testing.assert_close(loaded(x), model(x))
