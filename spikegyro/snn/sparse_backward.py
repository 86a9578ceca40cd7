"""Event-driven backward pass of one SRM conv layer on the CPU (Numba).

With a bounded surrogate, ∂L/∂u = ρ(u)·∂L/∂s is non-zero only at the (neuron, step) pairs that
:func:`spikegyro.snn.sparse_forward.layer_forward` recorded within the support. From those δ
alone, in reverse time (no gradient flows through the refractory feedback, as in SLAYER):

- PSP adjoint: ∂L/∂z[t] = Σ_{k≥1} ε[k]·δ[t + k] (ε[0] = 0), kept as a ring of L output maps into
  which each δ is added once per tap;
- weight gradient: ∂L/∂W[ky, kx, c, :] += value·∂L/∂z[t, pixel, :] for every input spike (or
  input value) at step t and every output pixel it reaches: the transpose of the forward
  scatter, from sparse inputs only;
- input gradient: ∂L/∂s_in[t] = convᵀ(∂L/∂z[t]), evaluated only at the pairs of the layer below
  that lie within *its* support (elsewhere its ρ is 0 and the value is never used).

Layouts as in :mod:`spikegyro.snn.sparse_forward` (channels-last flat indices, CSR by step).
"""

from __future__ import annotations

import numba
import numpy as np

_FUTURE = np.iinfo(np.int64).max


@numba.njit(cache=True, nogil=True, fastmath=True)
def _dot(a: np.ndarray, b: np.ndarray) -> float:
    total = a[0] * 0
    for o in range(a.size):
        total += a[o] * b[o]
    return total


@numba.njit(cache=True, nogil=True, fastmath=True)
def _weight_grad_at(
    grad_w: np.ndarray,
    slot: np.ndarray,
    touched: np.ndarray,
    horizon: int,
    index: np.ndarray,
    values: np.ndarray,
    start: int,
    stop: int,
    stride: int,
    in_width: int,
    out_width: int,
    rows: tuple[np.ndarray, np.ndarray],
    cols: tuple[np.ndarray, np.ndarray],
) -> None:
    """∂W[ky, kx, c, :] += value·∂L/∂z[pixel, :] for the inputs ``start:stop`` of one step."""
    kernel_w, cin, cout = grad_w.shape[1], grad_w.shape[2], grad_w.shape[3]
    for i in range(start, stop):
        pixel_in, c = divmod(index[i], cin)
        iy, ix = divmod(pixel_in, in_width)
        value = values[i]
        for oy in range(rows[0][iy], rows[1][iy] + 1):
            ky = iy - oy * stride
            for ox in range(cols[0][ix], cols[1][ix] + 1):
                kx = ix - ox * stride
                pixel = oy * out_width + ox
                if kx >= kernel_w or touched[pixel] > horizon:
                    continue  # ∂L/∂z is exactly 0 there
                row = grad_w[ky, kx, c]
                grad_z = slot[pixel * cout : (pixel + 1) * cout]
                for o in range(cout):
                    row[o] += value * grad_z[o]


@numba.njit(cache=True, nogil=True, fastmath=True)
def _input_grad_at(
    out: np.ndarray,
    weight: np.ndarray,
    slot: np.ndarray,
    touched: np.ndarray,
    horizon: int,
    index: np.ndarray,
    start: int,
    stop: int,
    stride: int,
    in_width: int,
    out_width: int,
    rows: tuple[np.ndarray, np.ndarray],
    cols: tuple[np.ndarray, np.ndarray],
) -> None:
    """out[i] = convᵀ(∂L/∂z)[index[i]] for the pairs ``start:stop`` of one step."""
    kernel_w, cin, cout = weight.shape[1], weight.shape[2], weight.shape[3]
    for i in range(start, stop):
        pixel_in, c = divmod(index[i], cin)
        iy, ix = divmod(pixel_in, in_width)
        total = out[i] * 0
        for oy in range(rows[0][iy], rows[1][iy] + 1):
            ky = iy - oy * stride
            for ox in range(cols[0][ix], cols[1][ix] + 1):
                kx = ix - ox * stride
                pixel = oy * out_width + ox
                if kx >= kernel_w or touched[pixel] > horizon:
                    continue
                total += _dot(weight[ky, kx, c], slot[pixel * cout : (pixel + 1) * cout])
        out[i] = total


@numba.njit(cache=True, nogil=True, fastmath=True)
def layer_backward(
    act_offsets: np.ndarray,
    act_index: np.ndarray,
    act_u: np.ndarray,
    grad_s: np.ndarray,
    surrogate: np.ndarray,
    eps: np.ndarray,
    out_shape: tuple[int, int],
    inputs: tuple[np.ndarray, np.ndarray, np.ndarray],
    in_width: int,
    weight: np.ndarray,
    stride: int,
    rows: tuple[np.ndarray, np.ndarray],
    cols: tuple[np.ndarray, np.ndarray],
    below: tuple[np.ndarray, np.ndarray],
    want_below: bool,
) -> tuple[np.ndarray, np.ndarray]:
    """Weight gradient of one layer and ∂L/∂s of the layer below at its active pairs.

    Args:
        act_offsets, act_index, act_u: this layer's pairs within the surrogate's support.
        grad_s: ∂L/∂s at those pairs (aligned with ``act_index``).
        surrogate: [θ, scale_rho/θ, −1/(tau_rho·θ)] in the weight's dtype: ρ(u) =
            scale_rho/θ·exp(−|u − θ|/(tau_rho·θ)) at the recorded pairs.
        eps: the PSP taps ε[0 … L−1] (ε[0] = 0), the weight's dtype.
        out_shape: (height, width) of the output map, px.
        inputs: (offsets, flat indices, values) of this layer's input, as in the forward pass.
        in_width: input map width; weight: (kh, kw, C_in, C_out); rows, cols: fan-out tables.
        below: (offsets, flat indices) of the active pairs of the layer below (the input side).
        want_below: compute ∂L/∂s there (False for the first layer that learns).

    Returns:
        (∂L/∂W (kh, kw, C_in, C_out), ∂L/∂s_in at the pairs of ``below``).
    """
    steps = act_offsets.size - 1
    cout = weight.shape[3]
    taps = eps.size
    out_width = out_shape[1]
    pixels = out_shape[0] * out_width
    in_offsets, in_index, in_values = inputs
    below_offsets, below_index = below
    theta, height, slope = surrogate[0], surrogate[1], surrogate[2]
    grad_w = np.zeros_like(weight)
    grad_below = np.zeros(below_index.size if want_below else 0, weight.dtype)
    ring = np.zeros((taps, pixels * cout), weight.dtype)
    # Earliest step whose δ was added at each pixel: ∂L/∂z[t] there may be non-zero only if it
    # is at most t + L − 1.
    touched = np.full(pixels, _FUTURE, np.int64)
    for t in range(steps - 1, -1, -1):
        slot = ring[t % taps]
        horizon = t + taps - 1
        _weight_grad_at(grad_w, slot, touched, horizon, in_index, in_values, in_offsets[t],
                        in_offsets[t + 1], stride, in_width, out_width, rows, cols)  # fmt: skip
        if want_below:
            _input_grad_at(grad_below, weight, slot, touched, horizon, below_index,
                           below_offsets[t], below_offsets[t + 1], stride, in_width, out_width,
                           rows, cols)  # fmt: skip
        for pixel in range(pixels):
            if touched[pixel] <= horizon:
                slot[pixel * cout : (pixel + 1) * cout] = 0.0
        for j in range(act_offsets[t], act_offsets[t + 1]):
            delta = height * np.exp(slope * abs(act_u[j] - theta)) * grad_s[j]
            n = act_index[j]
            for k in range(1, min(taps, t + 1)):
                ring[(t - k) % taps, n] += eps[k] * delta
            if t > 0:
                touched[n // cout] = t
    return grad_w, grad_below
