"""SNN-6 with a grid readout (the roll hypothesis variant): pooling and exact initialisation."""

from __future__ import annotations

import pytest
import torch

from spikegyro.errors import InputError
from spikegyro.models.registry import build_model
from spikegyro.models.snn6 import SNN6, grid_state_from_global
from spikegyro.snn.layers import GASP, RegionPool


def test_region_pool_matches_a_loop_over_cells() -> None:
    g = torch.Generator().manual_seed(0)
    spikes = (torch.rand(2, 3, 8, 12, 5, generator=g) < 0.3).float()
    pooled = RegionPool((2, 3))(spikes)
    assert pooled.shape == (2, 3 * 6, 5)
    for c in range(3):
        for i in range(2):
            for j in range(3):
                cell = spikes[:, c, 4 * i : 4 * i + 4, 4 * j : 4 * j + 4, :].mean(dim=(1, 2))
                torch.testing.assert_close(pooled[:, c * 6 + i * 3 + j], cell)
    torch.testing.assert_close(RegionPool((1, 1))(spikes), GASP()(spikes))


def test_grid_network_starts_as_the_global_one() -> None:
    torch.manual_seed(0)
    base = SNN6().eval()
    grid = build_model("snn6-grid", grid=(2, 2)).eval()  # 120x90: layer 5 is 4x2, cells 2x1
    grid.load_state_dict(grid_state_from_global(base.state_dict(), (2, 2)))
    x = (torch.rand(1, 2, 90, 120, 30) < 0.05).float()
    with torch.no_grad():
        torch.testing.assert_close(grid(x), base(x), rtol=1e-5, atol=1e-6)
    assert isinstance(build_model("snn6-grid", grid=(2, 3)).pool, RegionPool)
    with pytest.raises(InputError, match="already pools"):
        grid_state_from_global(grid.state_dict(), (2, 2))
