"""Stateful, event-driven execution of an SRM spiking network, one 1 ms step at a time.

The batch network computes, per layer, ``u = conv(psp(s_in)) + refractory(s_out)`` and spikes where
``u >= theta``, with truncated FIR kernels

    psp:        eps[k] = c k p^k          for 0 <= k < L   (c = e / tau_s, p = exp(-1 / tau_s))
    refractory: nu[0] = 0, nu[k] = a q^(k-1)  for 1 <= k < M   (a = -2 theta, q = exp(-1 / tau_r))

Both are linear, so the psp can be applied after the convolution: each layer keeps, per output
neuron, the state of the double pole ``(A, D)`` driven by ``W * s_in`` and a single pole ``R``
driven by the neuron's own spikes. The truncation of the batch kernels is reproduced exactly by
feeding each input a second time, L (or M) steps later, with the weight of the kernel's tail:

    A[t] = p A[t-1] + x[t] - p^L x[t-L]
    D[t] = p D[t-1] + p A[t-1] - L p^L x[t-L]          u[t] = c D[t] + R[t]
    R[t] = q R[t-1] + a s[t-1] - a q^(M-1) s[t-M]

(the impulse response of ``c D`` is ``c k p^k`` for k < L and exactly 0 from k = L on). These
are the exact kernels: a checkpoint's float32 taps differ from them by their rounding (≤ 6e-8
relative), so a float64 batch forward is matched to the last bits only with taps computed in
float64 (:meth:`spikegyro.snn.layers.SRMConv.exact_kernels`). The
synaptic input ``x = W * s_in`` is never stored as a map: each layer keeps the *lists* of input
spikes of its last L steps (and of its own spikes, M steps) and scatters them straight into the
state, once with weight 1 into ``A`` when they arrive and once with the tail weights into ``A``
and ``D`` L steps later. The only dense per-neuron memory is ``A, D, R`` (12 bytes a neuron in
float32: 4 MB for SNN-6 at 240x180, which stays in the last-level cache).

Work per step and layer (the kinds :attr:`StreamingSNN.profile` times):

- scatter: each input spike adds one column of 3x3 weights (``Cout`` values per reached output
  pixel) to ``A``; the spikes of L steps ago add it again, scaled, to ``A`` and ``D`` (tail);
- feedback: each output spike of one and of M steps ago touches its own ``R``;
- update: one fused pass over the output pixels touched in the last ``max(L, M)`` steps that
  thresholds ``u``, lists the neurons that fire and advances the recursions. A pixel untouched
  for longer holds exactly zero state (every contribution has been cancelled), so it is skipped.

The kernels run in Numba (compiled once, cached on disk): the inner loops are scatter-adds and
branchy per-pixel passes that vectorised NumPy/torch would either densify or pay for in
per-call overhead (a step is ~100 µs of work; a torch op costs ~5-10 µs to dispatch). With
``threads=2`` the layers are split in two groups that run as a pipeline on two cores, the first
group one block of ``block_steps`` ms ahead of the second. ``bench/streaming.py`` measures it
against the naive dense execution.
"""

from __future__ import annotations

import itertools
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numba
import numpy as np
from llvmlite import ir
from numba.core import cgutils, types
from numba.extending import intrinsic

from spikegyro.kernel_fit import fit_alpha_kernel, fit_exp_kernel

_NEG_BIG = -(1 << 40)


@dataclass(frozen=True)
class SRMLayerSpec:
    """One spiking conv layer (no padding, no bias).

    Attributes:
        weight: (Cout, Cin, kh, kw) float32 weights (cross-correlation, as ``torch.conv2d``).
        stride: spatial stride, pixels.
        theta: firing threshold.
        srm_kernel: the truncated psp kernel eps[0..L-1] the batch path applies (1 ms taps).
        ref_kernel: the truncated refractory kernel nu[0..M-1] (nu[0] = 0).
    """

    weight: np.ndarray
    stride: int
    theta: float
    srm_kernel: np.ndarray
    ref_kernel: np.ndarray


@dataclass(frozen=True)
class SNNSpec:
    """A stack of spiking conv layers, global average spike pooling, and a filtered dense readout.

    Attributes:
        input_shape: (channels, height, width) of the binary input spikes (channel 0 = OFF).
        layers: the spiking conv layers, in order.
        fc_weight: (outputs, channels of the last layer) readout weights.
        out_kernel: the psp kernel applied to the readout (1 ms taps).
    """

    input_shape: tuple[int, int, int]
    layers: tuple[SRMLayerSpec, ...]
    fc_weight: np.ndarray
    out_kernel: np.ndarray

    def layer_shapes(self) -> list[tuple[int, int, int]]:
        """(channels, height, width) of each layer's output."""
        c, h, w = self.input_shape
        shapes = []
        for layer in self.layers:
            kh, kw = layer.weight.shape[2:]
            h, w = (h - kh) // layer.stride + 1, (w - kw) // layer.stride + 1
            c = layer.weight.shape[0]
            shapes.append((c, h, w))
        return shapes


def _kx_order(kw: int, stride: int) -> np.ndarray:
    """Order of the kernel columns in the engine's weights: by kx mod stride, then descending, so
    that the columns ``kx, kx - stride, ...`` reaching the output pixels ``ox, ox + 1, ...``
    from one input pixel are adjacent, like those pixels' states."""
    return np.array(sorted(range(kw), key=lambda kx: (kx % stride, -kx)))


def _target_table(
    hin: int, win: int, hout: int, wout: int, kh: int, kw: int, stride: int
) -> np.ndarray:
    """Where each input pixel's spikes land, precomputed (integer division is slow in the scatter):
    per input row the first and last output row whose window holds it (o * stride + k = i,
    0 <= k < kh), then the same per input column, then per input column the place in
    :func:`_kx_order` of the kernel column that reaches the first of those; int64."""
    iy, ix = np.arange(hin), np.arange(win)
    ox0 = np.maximum(0, (ix - kw + stride) // stride)
    place = np.argsort(_kx_order(kw, stride))
    return np.concatenate([
        np.maximum(0, (iy - kh + stride) // stride), np.minimum(hout - 1, iy // stride),
        ox0, np.minimum(wout - 1, ix // stride), place[np.minimum(kw - 1, ix - ox0 * stride)],
    ]).astype(np.int64)  # fmt: skip


def _shift(n: int) -> int:
    """log2(n) where n is a power of two (division becomes a shift), else -1."""
    return n.bit_length() - 1 if n & (n - 1) == 0 else -1


RUN_GAP = 4
"""Default idle pixels the update pass advances rather than end a run of live ones."""

PROFILE_KINDS = ("scatter", "tail scatter", "feedback", "update")
"""Columns of :meth:`StreamingSNN.profile` for each layer (see the module docstring); its last
row holds the input binning and the readout in its first two columns."""


class StreamingSNN:
    """Run an :class:`SNNSpec` step by step with state carried across calls (event-driven).

    ``run(input_index, step_offsets)`` advances ``len(step_offsets) - 1`` steps of 1 ms; the input
    of step ``s`` is the set of active input units ``input_index[step_offsets[s]:
    step_offsets[s+1]]`` (flat indices ``(y * width + x) * 2 + polarity``, duplicates allowed).
    It returns the readout at each step, (steps, outputs) float64 — equal to the batch forward of
    the same spike tensor at those steps, whatever the threads and however the steps are split
    into calls.

    Args:
        spec: the network.
        dtype: dtype of the state and weights (float32, or float64 for bit-level comparisons).
        threads: 1, or 2 to run the layers as a two-stage pipeline on two cores (a call then
            returns once both stages have finished all its steps).
        block_steps: steps run layer by layer (a layer's weights stay in cache), and by which
            the first stage of the pipeline runs ahead of the second, ms.
        input_maps: per layer, keep the synaptic input as a ring of L + 1 maps (True) or scatter
            the input spikes a second time for the kernel's tail (False); default: maps where
            the input has more than 2 channels (a spike then reaches many weights).
        run_gap: up to this many idle pixels between two live ones are advanced with them (their
            state is exactly zero and stays so), so that the update pass starts fewer runs.
    """

    def __init__(
        self,
        spec: SNNSpec,
        dtype: type = np.float32,
        threads: int = 1,
        block_steps: int = 16,
        input_maps: tuple[bool, ...] | None = None,
        run_gap: int = RUN_GAP,
    ) -> None:
        if threads not in (1, 2) or block_steps < 1:
            raise ValueError(f"threads must be 1 or 2 and block_steps >= 1, got {threads}, "
                             f"{block_steps}")  # fmt: skip
        self.spec, self.threads, self.block_steps = spec, threads, block_steps
        self.run_gap = run_gap
        shapes = [spec.input_shape, *spec.layer_shapes()]
        n_layers = len(spec.layers)
        geo = np.zeros((n_layers, 10), dtype=np.int64)
        par = np.zeros((n_layers, 8), dtype=np.float64)
        klen = np.zeros((n_layers, 3), dtype=np.int64)  # L, M, input maps in a ring?
        if input_maps is None:
            input_maps = tuple(shape[0] > 2 for shape in shapes[:-1])
        weights, tabs, w_off, st_off, pos_off, z_off = [], [], [0], [0], [0], [0]
        for i, layer in enumerate(spec.layers):
            (cin, hin, win), (cout, hout, wout) = shapes[i], shapes[i + 1]
            kh, kw = layer.weight.shape[2:]
            c, p = fit_alpha_kernel(layer.srm_kernel, f"layer {i + 1} srm kernel")
            a, q = fit_exp_kernel(layer.ref_kernel, f"layer {i + 1} refractory kernel")
            big_l, big_m = len(layer.srm_kernel), len(layer.ref_kernel)
            klen[i] = big_l, big_m, bool(input_maps[i])
            geo[i] = (cin, hin, win, cout, hout, wout, layer.stride, kh * 1000 + kw, _shift(cin),
                      _shift(cout))  # fmt: skip
            tabs.append(_target_table(hin, win, hout, wout, kh, kw, layer.stride))
            # tail weights: A gets -p^L x[t-L], D gets -L p^L x[t-L], R gets -a q^(M-1) s[t-M]
            par[i] = (c, p, -(p**big_l), -big_l * p**big_l, a, q, -a * q ** (big_m - 1),
                      layer.theta)  # fmt: skip
            # (ky, cin, kx in _kx_order, cout): the weights one input unit sends to a row of
            # output pixels are adjacent
            ordered = layer.weight[:, :, :, _kx_order(kw, layer.stride)]
            weights.append(np.ascontiguousarray(ordered.transpose(2, 1, 3, 0)).ravel())
            w_off.append(w_off[-1] + weights[-1].size)
            st_off.append(st_off[-1] + cout * hout * wout)
            pos_off.append(pos_off[-1] + hout * wout)
            z_off.append(z_off[-1] + (big_l + 1) * cout * hout * wout * int(klen[i, 2]))
        # spike-list ring b holds the spikes entering layer b (b = 0: the input events); it reaches
        # back L steps for layer b's psp tail and M steps for layer b - 1's refractory tail; layer
        # b - 1 writes up to one block ahead of what layer b reads (two in a pipeline).
        slack = block_steps * threads
        reach = [max(klen[b, 0] if b < n_layers else 0, klen[b - 1, 1] if b else 0)
                 for b in range(n_layers + 1)]  # fmt: skip
        ring_len = np.array([r + 1 + slack for r in reach], dtype=np.int64)
        ring_cap = np.array([c_ * h_ * w_ for c_, h_, w_ in shapes], dtype=np.int64)
        # parameters in the state's dtype, so the inner loops never mix precisions
        self._geo, self._par, self._klen = geo, par.astype(dtype), klen
        self._w = np.concatenate(weights).astype(dtype)
        self._w_off = np.array(w_off, dtype=np.int64)
        self._tab = np.concatenate(tabs)
        self._tab_off = np.cumsum([0] + [len(tab) for tab in tabs], dtype=np.int64)
        self._st_off = np.array(st_off, dtype=np.int64)
        self._pos_off = np.array(pos_off, dtype=np.int64)
        self._z_off = np.array(z_off, dtype=np.int64)
        self._ring_len, self._ring_cap = ring_len, ring_cap
        self._ring_off = np.concatenate([[0], np.cumsum(ring_len * ring_cap)]).astype(np.int64)
        self._cnt_off = np.concatenate([[0], np.cumsum(ring_len)]).astype(np.int64)
        c_last, h_last, w_last = shapes[-1]
        fc = np.asarray(spec.fc_weight, dtype=np.float64).reshape(-1, c_last)
        self._fc = fc / (h_last * w_last)  # GASP's mean folded into the readout
        self._out_kernel = np.asarray(spec.out_kernel, dtype=np.float64)
        self._dtype = dtype
        self._pool: ThreadPoolExecutor | None = None
        self.reset()

    @property
    def steps_done(self) -> int:
        """Number of 1 ms steps advanced since the last reset."""
        return int(self._t)

    def reset(self) -> None:
        """Clear all state (as at the start of a recording) and the profile."""
        self._state = np.zeros((3, int(self._st_off[-1])), dtype=self._dtype)  # A, D, R
        self._z = np.zeros(int(self._z_off[-1]), dtype=self._dtype)
        self._last = np.full(int(self._pos_off[-1]), _NEG_BIG, dtype=np.int64)
        # only the first ring_cnt entries of a slot are ever read: no need to clear the rings
        self._ring = np.empty(int(self._ring_off[-1]), dtype=np.int32)
        self._ring_cnt = np.zeros(int(self._cnt_off[-1]), dtype=np.int64)
        self._seen = np.full(int(self._ring_cap[0]), _NEG_BIG, dtype=np.int64)
        self._h = np.zeros((len(self._out_kernel), self._fc.shape[0]), dtype=np.float64)
        self._t = 0
        self.spike_counts = np.zeros(len(self.spec.layers), dtype=np.int64)
        # the pipeline's balance learns from every recording, the profile from this one
        cycles = getattr(self, "_cycles", 0)
        self._cycles_before = cycles + getattr(self, "_cycles_before", 0)
        self._cycles = np.zeros((len(self.spec.layers) + 1, len(PROFILE_KINDS)), dtype=np.int64)

    def profile(self) -> np.ndarray:
        """CPU seconds spent since the last reset, (layers + 1, len(PROFILE_KINDS)): per layer
        and kind of work; the last row holds the input binning and the readout."""
        return self._cycles / _cycle_rate()

    def run(self, input_index: np.ndarray, step_offsets: np.ndarray) -> np.ndarray:
        """Advance ``len(step_offsets) - 1`` steps; returns the readout, (steps, outputs)."""
        input_index = np.ascontiguousarray(input_index, dtype=np.int64)
        step_offsets = np.ascontiguousarray(step_offsets, dtype=np.int64)
        n = len(step_offsets) - 1
        n_layers = len(self.spec.layers)
        out = np.zeros((n, self._fc.shape[0]), dtype=np.float64)
        # blocks bound the latency of a pipeline and keep a layer in cache for a few steps
        edges = [*range(0, n, self.block_steps), n]
        if self.threads == 1 or len(edges) < 3 or n_layers < 2:
            for s0, s1 in itertools.pairwise(edges):
                self._block(input_index, step_offsets, out, s0, s1, 0, n_layers)
        else:
            self._pipeline(input_index, step_offsets, out, edges, self._split())
        self._t += n
        return out

    def _block(self, inp, offs, out, s0: int, s1: int, l0: int, l1: int) -> None:
        """Steps ``s0..s1`` of this call through layers ``l0..l1`` (and the readout if last)."""
        _run_block(
            inp, offs, s0, s1, l0, l1, self._t, out, self._geo, self._par, self._klen, self._tab,
            self._tab_off, self._w, self._w_off, self._state, self._st_off, self._z, self._z_off,
            self._last, self._pos_off, self._ring, self._ring_off, self._ring_len, self._ring_cap,
            self._ring_cnt, self._cnt_off, self._seen, self._fc, self._out_kernel, self._h,
            self.spike_counts, self._cycles, self.run_gap,
        )  # fmt: skip

    def _pipeline(self, inp, offs, out, edges: list[int], split: int) -> None:
        """Layers ``< split`` run block b + 1 on this thread while the rest run block b.

        After 2 and 4 blocks, then every :data:`RESPLIT_BLOCKS`, the split is set again from the
        work done since the last setting.
        The first stage may give layers to the second at once (their state is a block ahead); to
        take layers back it first waits for the second stage to finish the block before.
        """
        if self._pool is None:
            self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="snn-stage2")
        n_layers = len(self.spec.layers)
        self._block(inp, offs, out, edges[0], edges[1], 0, split)
        seen = self._cycles.copy()
        for b in range(1, len(edges)):
            later = self._pool.submit(  # block b - 1, with the split its first half ran with
                self._block, inp, offs, out, edges[b - 1], edges[b], split, n_layers
            )
            try:
                if b + 1 < len(edges):
                    if b in (2, 4) or b % RESPLIT_BLOCKS == 0:  # early on: a new scene
                        new = self._split(self._cycles - seen)
                        seen = self._cycles.copy()
                        if new > split:
                            later.result()
                        split = new
                    self._block(inp, offs, out, edges[b], edges[b + 1], 0, split)
            finally:
                later.result()

    def _split(self, cycles: np.ndarray | None = None) -> int:
        """First layer of the pipeline's second stage: balances the work in ``cycles`` (default:
        profiled so far in every recording; the neuron counts before any profile exists)."""
        if cycles is None:
            cycles = self._cycles + self._cycles_before
        cycles = cycles.astype(np.float64)
        per_layer = cycles[:-1].sum(axis=1)
        per_layer[0] += cycles[-1, 0]  # input binning runs with layer 1, the readout with the last
        per_layer[-1] += cycles[-1, 1]
        if per_layer.sum() == 0:
            per_layer = (self._st_off[1:] - self._st_off[:-1]).astype(np.float64)
        first = np.cumsum(per_layer)[:-1]
        return int(np.argmin(np.maximum(first, per_layer.sum() - first))) + 1


RESPLIT_BLOCKS = 8
"""Blocks between two settings of the pipeline's split within a call (128 ms at 16 ms)."""


@intrinsic
def _rdtsc(typingctx):  # pragma: no cover
    """The CPU's cycle counter (0 where the target has none)."""

    def codegen(context, builder, signature, args):
        fn = cgutils.get_or_insert_function(
            builder.module, ir.FunctionType(ir.IntType(64), []), "llvm.readcyclecounter"
        )
        return builder.call(fn, [])

    return types.int64(), codegen


@intrinsic
def _cttz(typingctx, x):  # pragma: no cover
    """Number of trailing zero bits of a uint64 (one instruction; 64 for 0)."""

    def codegen(context, builder, signature, args):
        i64 = ir.IntType(64)
        fn = cgutils.get_or_insert_function(
            builder.module, ir.FunctionType(i64, [i64, ir.IntType(1)]), "llvm.cttz.i64"
        )
        return builder.call(fn, [args[0], ir.Constant(ir.IntType(1), 0)])

    return types.uint64(types.uint64), codegen


@numba.njit(cache=True)
def _cycles_now():  # pragma: no cover
    return _rdtsc()


_RATE: list[float] = []


def _cycle_rate() -> float:
    """Cycle counter ticks per second, measured once against ``time.perf_counter``."""
    if not _RATE:
        c0, t0 = _cycles_now(), time.perf_counter()
        time.sleep(0.02)
        c1, t1 = _cycles_now(), time.perf_counter()
        _RATE.append((c1 - c0) / (t1 - t0) if c1 > c0 else float("inf"))
    return _RATE[0]


@numba.njit(cache=True, nogil=True, fastmath=True)
def _scatter(spikes, g, tab, w, w0, za, zd, z0, last, p0, t, tail_a, tail_d):  # pragma: no cover
    """Add ``W[:, ci, ky, kx]`` to ``za[z0 + pixel * Cout:]`` for each output pixel a spike reaches
    (``A`` or a map of the ring) and mark the pixel touched at ``t``; with ``tail_a`` != 0, add
    it scaled by ``tail_a`` to ``za`` and by ``tail_d`` to ``zd`` (``A`` and ``D``) instead: the
    kernel's truncation, L steps later, when the pixel is still live. ``tab``: the layer's
    :func:`_target_table`."""
    cin, hin, win, cout, wout, stride, kw = g[0], g[1], g[2], g[3], g[5], g[6], g[7] % 1000
    cin_shift = g[8]
    tail = tail_a != 0.0
    n_spikes = spikes.shape[0]
    j = 0
    while j < n_spikes:
        # spikes of one input pixel (adjacent in the lists layers emit) share their targets
        pix = spikes[j] >> cin_shift if cin_shift >= 0 else spikes[j] // cin
        first_unit = pix * cin
        j_end = j + 1
        while j_end < n_spikes and first_unit <= spikes[j_end] < first_unit + cin:
            j_end += 1
        iy = pix // win
        ix = pix - iy * win
        oy0, oy1 = tab[iy], tab[hin + iy]
        ox0, ox1, place = tab[2 * hin + ix], tab[2 * hin + win + ix], tab[2 * hin + 2 * win + ix]
        # the targets of one output row are adjacent: one span of states, one span of weights
        span = (ox1 - ox0 + 1) * cout
        for oy in range(oy0, oy1 + 1 if span > 0 else oy0):
            ky = iy - oy * stride
            pos = oy * wout + ox0
            n0 = z0 + pos * cout
            # contiguous views: the channel loop vectorises (no index wrap-around checks)
            ra = za[n0 : n0 + span]
            tap = w0 + ((ky * cin - first_unit) * kw + place) * cout
            if tail:
                rd = zd[n0 : n0 + span]
                for jj in range(j, j_end):
                    wb = tap + spikes[jj] * kw * cout
                    col = w[wb : wb + span]
                    for co in range(span):
                        ra[co] += tail_a * col[co]
                        rd[co] += tail_d * col[co]
            else:
                last[p0 + pos : p0 + pos + ox1 - ox0 + 1] = t
                # two columns per pass over the targets: half their loads and stores
                jj = j
                while jj + 1 < j_end:
                    wb, wb2 = tap + spikes[jj] * kw * cout, tap + spikes[jj + 1] * kw * cout
                    col, col2 = w[wb : wb + span], w[wb2 : wb2 + span]
                    for co in range(span):
                        ra[co] += col[co] + col2[co]
                    jj += 2
                if jj < j_end:
                    wb = tap + spikes[jj] * kw * cout
                    col = w[wb : wb + span]
                    for co in range(span):
                        ra[co] += col[co]
        j = j_end


@numba.njit(cache=True, nogil=True, fastmath=True)
def _advance(st, mask, n0, n1, par):  # pragma: no cover
    """Neurons ``n0..n1`` (flat): mark u >= theta in ``mask``, step the recursions.

    One branch-free loop over contiguous memory, so it vectorises (8 lanes: no 64-bit counter).
    """
    c, p, q, theta = par[0], par[1], par[5], par[7]
    ra, rd, rr, mk = st[0, n0:n1], st[1, n0:n1], st[2, n0:n1], mask[: n1 - n0]
    for i in range(n1 - n0):
        a = ra[i]
        d = rd[i]
        mk[i] = c * d + rr[i] >= theta
        rd[i] = p * (d + a)
        ra[i] = p * a
        rr[i] = q * rr[i]


@numba.njit(cache=True, nogil=True, fastmath=True)
def _advance_ring(st, z, mask, n0, n1, zn0, zo0, par):  # pragma: no cover
    """:func:`_advance` for a layer whose synaptic input sits in a ring of maps: takes in x[t]
    (``z[zn0:]``) and the tail of x[t-L] (``z[zo0:]``, cleared for reuse as x[t+1])."""
    c, p, tail_a, tail_d, q, theta = par[0], par[1], par[2], par[3], par[5], par[7]
    ra, rd, rr = st[0, n0:n1], st[1, n0:n1], st[2, n0:n1]
    zn, zo, mk = z[zn0 : zn0 + n1 - n0], z[zo0 : zo0 + n1 - n0], mask[: n1 - n0]
    for i in range(n1 - n0):
        a = ra[i] + zn[i] + tail_a * zo[i]
        d = rd[i] + tail_d * zo[i]
        mk[i] = c * d + rr[i] >= theta
        rd[i] = p * (d + a)
        ra[i] = p * a
        rr[i] = q * rr[i]
        zo[i] = 0.0


@numba.njit(cache=True, nogil=True)
def _layer_pass(
    st, s0, z, zn, zo, last, p0, pos, n_pos, cout, t, horizon, par, mask, out, gap
):  # pragma: no cover
    """Advance every pixel ``pos..n_pos`` touched in the last ``horizon`` steps, in runs of
    adjacent pixels (bridging up to ``gap`` idle ones); write the flat indices of the neurons that
    fired to ``out``; returns their number."""
    n_spk = 0
    while pos < n_pos:
        age = t - last[p0 + pos]
        if age > horizon:
            pos += 1
            continue
        if age == horizon:  # every contribution has expired: drop the rounding residue
            n0 = s0 + pos * cout
            st[:, n0 : n0 + cout] = 0.0
            pos += 1
            continue
        end = pos + 1
        while end < n_pos:
            if t - last[p0 + end] < horizon:
                end += 1
                continue
            # a few idle pixels (state exactly zero, or zeroed here) cost less to advance with
            # the run than a new run costs to start
            ahead = end
            while ahead < min(n_pos, end + gap) and t - last[p0 + ahead] >= horizon:
                ahead += 1
            if ahead == n_pos or t - last[p0 + ahead] >= horizon:
                break
            for q in range(end, ahead):
                if t - last[p0 + q] == horizon:
                    st[:, s0 + q * cout : s0 + (q + 1) * cout] = 0.0
            end = ahead + 1
        n0, n1 = s0 + pos * cout, s0 + end * cout
        if zn < 0:
            _advance(st, mask, n0, n1, par)
        else:
            _advance_ring(st, z, mask, n0, n1, zn + pos * cout, zo + pos * cout, par)
        # spikes are sparse: eight flags (bytes 0/1) a word, set bits found by counting zeros
        words = mask.view(np.uint64)
        n_words, rest = (n1 - n0) // 8, (n1 - n0) % 8
        for k in range(n_words + (rest > 0)):
            word = words[k]
            if k == n_words:  # flags past the run are stale
                word &= (np.uint64(1) << np.uint64(8 * rest)) - np.uint64(1)
            while word:
                out[n_spk] = n0 - s0 + 8 * k + (_cttz(word) >> np.uint64(3))
                n_spk += 1
                word &= word - np.uint64(1)
        pos = end
    return n_spk


@numba.njit(cache=True, nogil=True)
def _spikes(ring, off, length, cap, ring_cnt, cnt_off, t):  # pragma: no cover
    """Step ``t``'s spike list of a ring, as a view."""
    base = off + (t % length) * cap
    return ring[base : base + ring_cnt[cnt_off + t % length]]


@numba.njit(cache=True, nogil=True)
def _bin_input(
    inp, offs, s_begin, s_end, t_base, ring, ring_off, ring_len, ring_cap, ring_cnt, cnt_off, seen,
    cycles,
):  # pragma: no cover  # fmt: skip
    """Each step's input events, deduplicated (the input is binary), into ring 0 in arrival
    order (sorting them cost more than the locality it bought the layer-1 scatter)."""
    for s in range(s_begin, s_end):
        t = t_base + s
        c0 = _rdtsc()
        r0 = ring_off[0] + (t % ring_len[0]) * ring_cap[0]
        m = 0
        for e in range(offs[s], offs[s + 1]):
            idx = inp[e]
            if seen[idx] != t:
                seen[idx] = t
                ring[r0 + m] = idx
                m += 1
        ring_cnt[cnt_off[0] + t % ring_len[0]] = m
        cycles[cycles.shape[0] - 1, 0] += _rdtsc() - c0


@numba.njit(cache=True, nogil=True)
def _feedback(st, s0, last, p0, own, amp, t, mark, cout, cout_shift):  # pragma: no cover
    """Add ``amp`` to the refractory state of the neurons in ``own`` (a spike list); with
    ``mark``, mark their pixels touched at ``t``."""
    for n in own:
        st[2, s0 + n] += amp
        if mark:
            last[p0 + (n >> cout_shift if cout_shift >= 0 else n // cout)] = t


@numba.njit(cache=True, nogil=True)
def _layer_block(
    li, s_begin, s_end, t_base, geo, par, klen, tab, tab_off, w, w_off, st, st_off, z, z_off, last,
    pos_off, ring, ring_off, ring_len, ring_cap, ring_cnt, cnt_off, spike_counts, cycles, mask,
    gap,
):  # pragma: no cover  # fmt: skip
    """Steps ``s_begin..s_end`` of layer ``li``: scatter its input spikes (and their tail L steps
    later), the refractory feedback of its own, then the update pass into its output ring."""
    g = geo[li]
    cout, cout_shift = g[3], g[9]
    big_l, big_m = klen[li, 0], klen[li, 1]
    s0, p0 = st_off[li], pos_off[li]
    n_neurons = g[4] * g[5] * cout
    tb = tab[tab_off[li] : tab_off[li + 1]]
    for s in range(s_begin, s_end):
        t = t_base + s
        c0 = _rdtsc()
        spikes = _spikes(ring, ring_off[li], ring_len[li], ring_cap[li], ring_cnt, cnt_off[li], t)
        if klen[li, 2]:  # synaptic input into map t of the ring, read back L steps later
            zn = z_off[li] + (t % (big_l + 1)) * n_neurons
            zo = z_off[li] + ((t + 1) % (big_l + 1)) * n_neurons
            _scatter(spikes, g, tb, w, w_off[li], z, z, zn, last, p0, t, 0.0, 0.0)
        else:
            zn = zo = -1
            _scatter(spikes, g, tb, w, w_off[li], st[0], st[1], s0, last, p0, t, 0.0, 0.0)
        c1 = _rdtsc()
        cycles[li, 0] += c1 - c0
        if zn < 0 and t >= big_l:  # the same spikes L steps later, with the tail weights
            spikes = _spikes(ring, ring_off[li], ring_len[li], ring_cap[li], ring_cnt,
                             cnt_off[li], t - big_l)  # fmt: skip
            _scatter(spikes, g, tb, w, w_off[li], st[0], st[1], s0, last, p0, t, par[li, 2],
                     par[li, 3])  # fmt: skip
        c2 = _rdtsc()
        cycles[li, 1] += c2 - c1
        # refractory feedback of this layer's own spikes, one step and M steps ago
        for lag in (1, big_m):
            if t >= lag:
                own = _spikes(ring, ring_off[li + 1], ring_len[li + 1], ring_cap[li + 1],
                              ring_cnt, cnt_off[li + 1], t - lag)  # fmt: skip
                amp = par[li, 4] if lag == 1 else par[li, 6]
                _feedback(st, s0, last, p0, own, amp, t, lag == 1, cout, cout_shift)
        c3 = _rdtsc()
        cycles[li, 2] += c3 - c2
        cnt = cnt_off[li + 1] + t % ring_len[li + 1]
        obase = ring_off[li + 1] + (t % ring_len[li + 1]) * ring_cap[li + 1]
        n_spk = _layer_pass(
            st, s0, z, zn, zo, last, p0, 0, g[4] * g[5], cout, t, max(big_l, big_m) + 1,
            par[li], mask, ring[obase : obase + ring_cap[li + 1]], gap,
        )  # fmt: skip
        ring_cnt[cnt] = n_spk
        spike_counts[li] += n_spk
        cycles[li, 3] += _rdtsc() - c3


@numba.njit(cache=True, nogil=True)
def _readout(
    s_begin, s_end, t_base, out, cout, ring, off, length, cap, ring_cnt, cnt_off, fc, kout, hring,
    cycles,
):  # pragma: no cover  # fmt: skip
    """Readout of steps ``s_begin..s_end``: global average of the last layer's spikes (ring at
    ``off``) -> dense -> psp (exact FIR over ``hring``), into ``out[s]``."""
    n_out = fc.shape[0]
    lo = kout.shape[0]
    for s in range(s_begin, s_end):
        t = t_base + s
        c0 = _rdtsc()
        hslot = t % lo
        for o in range(n_out):
            hring[hslot, o] = 0.0
        slot = t % length
        base = off + slot * cap
        for j in range(ring_cnt[cnt_off + slot]):
            ch = ring[base + j] % cout
            for o in range(n_out):
                hring[hslot, o] += fc[o, ch]
        for o in range(n_out):
            acc = 0.0
            for k in range(min(lo, t + 1)):
                acc += kout[k] * hring[(t - k) % lo, o]
            out[s, o] = acc
        cycles[cycles.shape[0] - 1, 1] += _rdtsc() - c0


@numba.njit(cache=True, nogil=True)
def _run_block(  # pragma: no cover
    inp, offs, s_begin, s_end, l0, l1, t_base, out, geo, par, klen, tab, tab_off, w, w_off, st,
    st_off, z,
    z_off, last, pos_off, ring, ring_off, ring_len, ring_cap, ring_cnt, cnt_off, seen, fc, kout,
    hring, spike_counts, cycles, gap,
):  # fmt: skip
    n_layers = geo.shape[0]
    mask = np.zeros(8 * (ring_cap[1:].max() // 8 + 1), dtype=np.uint8)
    if l0 == 0:
        _bin_input(inp, offs, s_begin, s_end, t_base, ring, ring_off, ring_len, ring_cap, ring_cnt,
                   cnt_off, seen, cycles)  # fmt: skip
    # layer by layer over the block, so that a layer's state and weights stay in cache
    for li in range(l0, l1):
        _layer_block(
            li, s_begin, s_end, t_base, geo, par, klen, tab, tab_off, w, w_off, st, st_off, z,
            z_off, last, pos_off, ring, ring_off, ring_len, ring_cap, ring_cnt, cnt_off,
            spike_counts, cycles, mask, gap,
        )  # fmt: skip
    if l1 == n_layers:
        _readout(
            s_begin, s_end, t_base, out, geo[n_layers - 1, 3], ring, ring_off[n_layers],
            ring_len[n_layers], ring_cap[n_layers], ring_cnt, cnt_off[n_layers], fc, kout, hring,
            cycles,
        )  # fmt: skip
