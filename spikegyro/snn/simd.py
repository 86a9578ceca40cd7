"""Row kernels of the event-driven engine as explicit vector code (Numba intrinsics, LLVM IR).

The engine's scatters and gathers move one row of C_out weights or gradients per (input, tap),
and the inputs of one pixel share their target row. Written as Numba loops, each row is a
separate vectorised loop whose target is loaded and stored again for every input, and whose
operand is reloaded for every input, since Numba cannot tell that the arrays do not overlap.
These intrinsics keep the shared row in vector registers across the inputs of a pixel: 16
float32 (or 8 float64) lanes per register, unrolled for rows of 1, 2 or 4 registers (16, 32 and
64 float32 channels), a loop over registers for other multiples and a scalar loop for the rest.
The generic LLVM vector types compile for any target (on AVX-512 one register per 16 float32).

``add_rows`` adds in the order of the Numba loop it replaces, product then sum, so that the
forward pass's potentials are unchanged to the last bit; ``add_scaled`` and ``dot_rows`` serve the
backward pass, whose sums may run in any order (fast-math flags, as the kernels they serve).
"""

from __future__ import annotations

from collections.abc import Callable

from llvmlite import ir
from numba.core import cgutils, types
from numba.extending import intrinsic

_I64 = ir.IntType(64)
_FAST = ("fast",)
_UNROLLED = (1, 2, 4)  # registers per row that get straight-line code


def _contiguous(*arrays: types.Type) -> bool:
    """Whether every argument is a C-contiguous float array of one dtype (the rows are read
    as consecutive vectors)."""
    return all(
        isinstance(a, types.Array) and a.layout == "C" and a.dtype == arrays[0].dtype
        and a.dtype in (types.float32, types.float64)
        for a in arrays
    )  # fmt: skip


def _const(n: int) -> ir.Constant:
    return ir.Constant(_I64, n)


def _lanes(dtype: types.Type) -> int:
    return 16 if dtype == types.float32 else 8


def _int64(builder: ir.IRBuilder, value: ir.Value) -> ir.Value:
    return builder.sext(value, _I64) if value.type.width < 64 else value


def _splat(builder: ir.IRBuilder, value: ir.Value, vec: ir.VectorType) -> ir.Value:
    lanes = vec.count
    one = builder.insert_element(ir.Constant(vec, ir.Undefined), value, ir.Constant(_I64, 0))
    zeros = ir.Constant(ir.VectorType(ir.IntType(32), lanes), [0] * lanes)
    return builder.shuffle_vector(one, one, zeros)


def _vector_at(builder: ir.IRBuilder, data: ir.Value, offset: ir.Value, vec: ir.VectorType):
    """Pointer to the vector of ``vec`` at element ``offset`` of ``data``."""
    return builder.bitcast(builder.gep(data, [offset]), vec.as_pointer())


def _horizontal_sum(builder: ir.IRBuilder, value: ir.Value, lanes: int) -> ir.Value:
    while lanes > 1:
        half = lanes // 2
        low = ir.Constant(ir.VectorType(ir.IntType(32), half), list(range(half)))
        high = ir.Constant(ir.VectorType(ir.IntType(32), half), list(range(half, lanes)))
        value = builder.fadd(
            builder.shuffle_vector(value, value, low),
            builder.shuffle_vector(value, value, high),
            flags=_FAST,
        )
        lanes = half
    return builder.extract_element(value, ir.Constant(ir.IntType(32), 0))


def _by_width(
    builder: ir.IRBuilder,
    width: ir.Value,
    lanes: int,
    unrolled: Callable[[int], None],
    generic: Callable[[], None],
) -> None:
    """unrolled(k) where the row ``width`` is k registers (k in _UNROLLED), else generic()."""

    def emit(ks: tuple[int, ...]) -> None:
        if not ks:
            generic()
            return
        match = builder.icmp_signed("==", width, _const(ks[0] * lanes))
        with builder.if_else(match) as (then, otherwise):
            with then:
                unrolled(ks[0])
            with otherwise:
                emit(ks[1:])

    emit(_UNROLLED)


def _span_loop(builder: ir.IRBuilder, span: ir.Value):
    """for e in range(*span) (a (start, stop) tuple of integers)."""
    start, stop = (_int64(builder, v) for v in cgutils.unpack_tuple(builder, span, 2))
    return cgutils.for_range_slice(builder, start, stop, _const(1))


class _Rows:
    """The arrays of a row kernel's call: a row width, a matrix of rows picked by ``index[e] −
    offset`` and the entries' values."""

    def __init__(
        self, context, builder, signature, args, row_arg: int, matrix_arg: int, values: bool
    ) -> None:
        tys = signature.args
        self.builder = builder
        self.values = context.make_array(tys[3])(context, builder, args[3]) if values else None
        self.row = context.make_array(tys[row_arg])(context, builder, args[row_arg])
        self.matrix = context.make_array(tys[matrix_arg])(context, builder, args[matrix_arg])
        self.index = context.make_array(tys[2])(context, builder, args[2])
        self.width = builder.extract_value(self.row.shape, 0)
        self.scalar = context.get_value_type(tys[row_arg].dtype)
        self.lanes = _lanes(tys[row_arg].dtype)
        self.vec = ir.VectorType(self.scalar, self.lanes)

    def start_of(self, e: ir.Value, offset: ir.Value) -> ir.Value:
        """Element offset of row index[e] − offset in the matrix."""
        b = self.builder
        row = b.sub(_int64(b, b.load(b.gep(self.index.data, [e]))), _int64(b, offset))
        return b.mul(row, self.width)

    def value(self, e: ir.Value) -> ir.Value:
        """values[e] (argument 3)."""
        return self.builder.load(self.builder.gep(self.values.data, [e]))

    def row_chunk(self, k: int | ir.Value) -> ir.Value:
        """Pointer to register k of the row."""
        return self.chunk(self.row.data, _const(0), k)

    def chunk(self, data: ir.Value, offset: ir.Value, k: int | ir.Value) -> ir.Value:
        """Pointer to register k of a row starting at element ``offset`` of ``data``."""
        b = self.builder
        step = _const(k * self.lanes) if isinstance(k, int) else b.mul(k, _const(self.lanes))
        return _vector_at(b, data, b.add(offset, step), self.vec)

    def chunks(self) -> ir.Value:
        return self.builder.udiv(self.width, _const(self.lanes))

    def scalar_tail(self) -> tuple[ir.Value, ir.Value]:
        """(first, stop) of the row's elements after its whole registers."""
        return self.builder.mul(self.chunks(), _const(self.lanes)), self.width


@intrinsic
def add_rows(typingctx, target, rows, index, values, span, offset):
    """target[:] += Σ values[e]·rows[index[e] − offset, :] over e in range(*span), each
    product added in turn as ``target[o] += values[e] * rows[...][o]`` would (target: 1-d;
    rows: 2-d C-contiguous, as wide as target; values: the entries' multipliers)."""
    if not _contiguous(target, rows, values):
        return None
    sig = types.void(target, rows, index, values, span, offset)

    def codegen(context, builder, signature, args):
        r = _Rows(context, builder, signature, args, 0, 1, values=True)

        def summed(ks) -> None:
            """Registers ks of the target, each summed over the entries in a register."""
            targets = [r.row_chunk(k) for k in ks]
            accs = [cgutils.alloca_once(builder, r.vec) for _ in ks]
            for at, acc in zip(targets, accs, strict=True):
                builder.store(builder.load(at, align=4), acc)
            with _span_loop(builder, args[4]) as (e, _):
                start = r.start_of(e, args[5])
                v = _splat(builder, r.value(e), r.vec)
                for k, acc in zip(ks, accs, strict=True):
                    w = builder.load(r.chunk(r.matrix.data, start, k), align=4)
                    builder.store(builder.fadd(builder.load(acc), builder.fmul(w, v)), acc)
            for at, acc in zip(targets, accs, strict=True):
                builder.store(builder.load(acc), at, align=4)

        def unrolled(k: int) -> None:
            summed(range(k))

        def generic() -> None:
            with cgutils.for_range(builder, r.chunks()) as loop:
                summed([loop.index])
            first, stop = r.scalar_tail()
            with cgutils.for_range_slice(builder, first, stop, _const(1)) as (o, _):
                at = builder.gep(r.row.data, [o])
                with _span_loop(builder, args[4]) as (e, _):
                    at_w = builder.gep(r.matrix.data, [builder.add(r.start_of(e, args[5]), o)])
                    w = builder.load(at_w)
                    v = r.value(e)
                    builder.store(builder.fadd(builder.load(at), builder.fmul(w, v)), at)

        _by_width(builder, r.width, r.lanes, unrolled, generic)
        return context.get_dummy_value()

    return sig, codegen


@intrinsic
def add_scaled(typingctx, rows, row, index, values, span, offset):
    """rows[index[e] − offset, :] += values[e]·row for e in range(*span), with ``row`` held in
    registers (rows: 2-d C-contiguous, as wide as row; fast-math sums)."""
    if not _contiguous(rows, row, values):
        return None
    sig = types.void(rows, row, index, values, span, offset)

    def codegen(context, builder, signature, args):
        r = _Rows(context, builder, signature, args, 1, 0, values=True)

        def update(e: ir.Value, ks, registers) -> None:
            start = r.start_of(e, args[5])
            v = _splat(builder, r.value(e), r.vec)
            for k, g in zip(ks, registers, strict=True):
                at = r.chunk(r.matrix.data, start, k)
                total = builder.fadd(builder.load(at, align=4), builder.fmul(g, v, flags=_FAST),
                                     flags=_FAST)  # fmt: skip
                builder.store(total, at, align=4)

        def unrolled(n: int) -> None:
            registers = [builder.load(r.row_chunk(k), align=4) for k in range(n)]
            with _span_loop(builder, args[4]) as (e, _):
                update(e, range(n), registers)

        def generic() -> None:  # rows in memory, entry by entry, as a Numba loop would
            with _span_loop(builder, args[4]) as (e, _):
                with cgutils.for_range(builder, r.chunks()) as loop:
                    g = builder.load(r.row_chunk(loop.index), align=4)
                    update(e, [loop.index], [g])
                first, stop = r.scalar_tail()
                start = r.start_of(e, args[5])
                v = r.value(e)
                with cgutils.for_range_slice(builder, first, stop, _const(1)) as (o, _):
                    g = builder.load(builder.gep(r.row.data, [o]))
                    at = builder.gep(r.matrix.data, [builder.add(start, o)])
                    total = builder.fadd(builder.load(at), builder.fmul(g, v, flags=_FAST),
                                         flags=_FAST)  # fmt: skip
                    builder.store(total, at)

        _by_width(builder, r.width, r.lanes, unrolled, generic)
        return context.get_dummy_value()

    return sig, codegen


@intrinsic
def dot_rows(typingctx, out, rows, index, row, span, offset):
    """out[e − span[0]] += rows[index[e] − offset, :]·row for e in range(*span), with ``row``
    held in registers (rows: 2-d C-contiguous, as wide as row; fast-math sums)."""
    if not _contiguous(out, rows, row):
        return None
    sig = types.void(out, rows, index, row, span, offset)

    def codegen(context, builder, signature, args):
        r = _Rows(context, builder, signature, args, 3, 1, values=False)
        res = context.make_array(signature.args[0])(context, builder, args[0])
        first_e = _int64(builder, cgutils.unpack_tuple(builder, args[4], 2)[0])

        def accumulate(e: ir.Value, total: ir.Value) -> None:
            at = builder.gep(res.data, [builder.sub(e, first_e)])
            builder.store(builder.fadd(builder.load(at), total, flags=_FAST), at)

        def block(start: ir.Value, first: int | ir.Value, n: int, registers=None) -> ir.Value:
            """Σ over registers first … first + n − 1 of row·rows[...] (one vector)."""
            terms = []
            for k in range(n):
                at = k if isinstance(first, int) else builder.add(first, _const(k))
                g = registers[k] if registers else builder.load(r.row_chunk(at))
                w = builder.load(r.chunk(r.matrix.data, start, at), align=4)
                terms.append(builder.fmul(w, g, flags=_FAST))
            while len(terms) > 1:  # pairwise: independent additions, not a chain
                pairs = zip(terms[::2], terms[1::2], strict=True)
                terms = [builder.fadd(a, b, flags=_FAST) for a, b in pairs]
            return terms[0]

        def unrolled(n: int) -> None:
            registers = [builder.load(r.row_chunk(k), align=4) for k in range(n)]
            with _span_loop(builder, args[4]) as (e, _):
                total = block(r.start_of(e, args[5]), 0, n, registers)
                accumulate(e, _horizontal_sum(builder, total, r.lanes))

        def generic() -> None:  # row from memory, four registers at a time
            quads = builder.udiv(r.chunks(), _const(4))
            with _span_loop(builder, args[4]) as (e, _):
                start = r.start_of(e, args[5])
                accs = [
                    cgutils.alloca_once_value(builder, ir.Constant(r.vec, None)) for _ in range(4)
                ]
                with cgutils.for_range(builder, quads) as loop:
                    first = builder.mul(loop.index, _const(4))
                    for k, acc in enumerate(accs):
                        at = builder.add(first, _const(k))
                        g = builder.load(r.row_chunk(at), align=4)
                        w = builder.load(r.chunk(r.matrix.data, start, at), align=4)
                        total = builder.fadd(
                            builder.load(acc), builder.fmul(w, g, flags=_FAST), flags=_FAST
                        )
                        builder.store(total, acc)
                acc = accs[0]
                pair = [
                    builder.fadd(builder.load(accs[0]), builder.load(accs[1]), flags=_FAST),
                    builder.fadd(builder.load(accs[2]), builder.load(accs[3]), flags=_FAST),
                ]
                builder.store(builder.fadd(pair[0], pair[1], flags=_FAST), acc)
                with cgutils.for_range_slice(
                    builder, builder.mul(quads, _const(4)), r.chunks(), _const(1)
                ) as (k, _):
                    builder.store(
                        builder.fadd(builder.load(acc), block(start, k, 1), flags=_FAST), acc
                    )
                total = cgutils.alloca_once_value(
                    builder, _horizontal_sum(builder, builder.load(acc), r.lanes)
                )
                first, stop = r.scalar_tail()
                with cgutils.for_range_slice(builder, first, stop, _const(1)) as (o, _):
                    w = builder.load(builder.gep(r.matrix.data, [builder.add(start, o)]))
                    g = builder.load(builder.gep(r.row.data, [o]))
                    product = builder.fmul(w, g, flags=_FAST)
                    builder.store(builder.fadd(builder.load(total), product, flags=_FAST), total)
                accumulate(e, builder.load(total))

        _by_width(builder, r.width, r.lanes, unrolled, generic)
        return context.get_dummy_value()

    return sig, codegen
