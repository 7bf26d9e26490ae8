"""Run a function written once against the array interface: compiled by Dr.Jit, or as eager torch.

The bounce's detached maths (hit decode, emitter and BSDF sampling, throughput, roulette, the
counter-based random numbers) is written once, per component and with masks, against the array
interface of :mod:`invrender.backends.arrays`. :func:`run` evaluates such a function on torch
tensors:

- with Dr.Jit (``llvm`` on the CPU, ``cuda`` on CUDA) where it is importable and its backend loads:
  the call is traced and compiled into one kernel (SIMD across lanes on the CPU), cached in memory
  and on disk by Dr.Jit (``~/.drjit``), so a kernel compiles once per machine; tensors go in and
  come out without copies;
- else, or with ``INVRENDER_BOUNCE=torch``, as eager torch: the reference (the tests hold the
  compiled results to it: the same random bits, floats within rounding).

Neither carries autograd through a compiled call: callers pass detached inputs (sampling and hit
geometry are detached by design; gradients flow through the torch bounce's evaluation of the
parameters).
"""

from __future__ import annotations

import contextlib
import functools
import os
import threading

import torch

from invrender.errors import ParameterError
from invrender.backends import arrays
from invrender.backends.arrays import TORCH, Columns


class Opaque:
    """A scalar argument that changes from call to call, a 32-bit unsigned int (a bounce's salts)
    or a float (an emitter type's share): passed to a compiled kernel as a value, not compiled into
    it."""

    __slots__ = ("value",)

    def __init__(self, value: int | float):
        self.value = value


class Sums:
    """A flat float64 accumulator that calls add to in place (:meth:`scatter_add_rows
    <invrender.backends.arrays.TorchArrays.scatter_add_rows>`): per pixel sums that a render's
    every bounce adds to (a per-pixel Jacobian). Passed to :func:`run` as an argument; under
    Dr.Jit it lives as one Dr.Jit array between calls (no copy per call), as a torch tensor
    otherwise.

    Attributes:
        size: its floats; device: the device of its tensor.
    """

    def __init__(self, size: int, device: torch.device):
        self.size, self.device = size, device
        self._tensor, self._drjit, self._zero = torch.zeros(size, dtype=torch.float64, device=device), None, True

    def on(self, xp):
        """The accumulator as ``xp``'s array (a call adds to it in place)."""
        if xp is TORCH:
            self._zero = False
            return self.tensor()
        if self._drjit is None:  # Dr.Jit's own memory from here on, never a view of torch's (whose
            # release inside a kernel's launch would need the GIL: DrJitArrays.from_torch)
            if self._zero:
                self._drjit = xp.dr.zeros(xp.Float64, self.size)
            else:
                self._drjit = xp.Float64(self._tensor) + 0.0
                xp.dr.eval(self._drjit)
            self._tensor = None
        return self._drjit

    def tensor(self) -> torch.Tensor:
        """(size,) float64: the sums so far."""
        if self._drjit is not None:
            with _DRJIT:
                xp = arrays.drjit_arrays(self.device)
                xp.dr.eval(self._drjit)
                xp.dr.sync_thread()
                self._tensor, self._drjit = torch.from_dlpack(self._drjit).clone(), None
        return self._tensor


def namespace(device: torch.device):
    """The array namespace :func:`run` evaluates with on ``device``: Dr.Jit's where it loads and
    ``INVRENDER_BOUNCE`` is not ``torch``, else :data:`~invrender.backends.arrays.TORCH`. Another
    value of the variable is a one-line :class:`~invrender.errors.ParameterError`."""
    choice = os.environ.get(arrays.ENV, "drjit")
    if choice not in arrays.CHOICES:
        raise ParameterError(f"{arrays.ENV} must be {' or '.join(map(repr, arrays.CHOICES))}, got {choice!r}")
    if choice == "torch" or device.type not in ("cpu", "cuda"):
        return TORCH
    return arrays.drjit_arrays(device) or TORCH


def run(fn, device: torch.device, *args, unstacked: bool = False, **static) -> tuple[torch.Tensor, ...]:
    """``fn(xp, *args, **static)`` evaluated on ``device``'s namespace (:func:`namespace`).

    Args:
        fn: a function written against the array interface returning a tuple of arrays and
            2- or 3-tuples of Float arrays, each of the lanes' length.
        args: torch tensors (1-D: lanes or flat tables; 2-D (N, 3): lanes of 3-vectors, passed as
            three columns, without a copy where they are stored by columns), :class:`Columns`
            (lanes of 3-vectors), :class:`Opaque` scalars, Python numbers.
        unstacked: k-tuples returned as :class:`Columns` rather than (N, k) tensors.
        static: Python values that choose the code (flags), the same for every lane.
    Returns:
        torch tensors on ``device``: (N,) per array, (N, k) per k-tuple, stored by columns (a
        view of a (k, N) tensor: the next call reads its columns without a copy), or with
        ``unstacked`` :class:`Columns`; UInt arrays as int32.
    """
    xp = namespace(device)
    if xp is not TORCH and any((isinstance(a, torch.Tensor) and not a.shape[0]) or (isinstance(a, Columns) and not a.lanes) for a in args):
        xp = TORCH  # no lanes (Dr.Jit has no empty arrays to broadcast against)
    return evaluate(xp, fn, *args, unstacked=unstacked, **static)


@contextlib.contextmanager
def in_calling_threads(device: torch.device):
    """Within the block (a render: :func:`invrender.core.driver.for_each_chunk`), Dr.Jit's LLVM
    kernels run in the threads that launch them, its thread pool emptied: a render parallelizes
    across its chunks, one worker per core, and a kernel split over the pool as well would
    oversubscribe the cores. The pool's size is restored when the last such block ends, so Dr.Jit's
    other users in the process keep theirs (Mitsuba 3 loads scenes in parallel on it: with an empty
    pool, its reads of EXR files waited minutes)."""
    xp = namespace(device)
    if xp is TORCH or not xp.name.endswith("llvm"):
        yield
        return
    global _pool_users, _pool_size
    with _POOL:
        if not _pool_users:
            _pool_size = xp.dr.thread_count()
            xp.dr.set_thread_count(0)
        _pool_users += 1
    try:
        yield
    finally:
        with _POOL:
            _pool_users -= 1
            if not _pool_users:
                xp.dr.set_thread_count(_pool_size)


#: the renders inside :func:`in_calling_threads` and the pool's size before the first of them
_POOL = threading.Lock()
_pool_users, _pool_size = 0, 0


def evaluate(xp, fn, *args, unstacked: bool = False, **static) -> tuple[torch.Tensor, ...]:
    """:func:`run` with the namespace given (the tests run both on the same inputs)."""
    if xp is TORCH:
        out = fn(xp, *(_argument(xp, a) for a in args), **static)
        return tuple(Columns(o) if unstacked and isinstance(o, tuple) else xp.to_torch(o) for o in out)
    if xp.name.endswith("cuda"):
        torch.cuda.current_stream().synchronize()  # torch's writes done before Dr.Jit's stream reads them
    lanes = _lanes(args)
    if lanes < FREEZE_LANES:  # padded: the same frozen kernel's arithmetic, whatever the chunking
        padded = evaluate(xp, fn, *_padded(args, lanes), unstacked=unstacked, **static)
        return tuple(Columns(c[:lanes] for c in r) if isinstance(r, Columns) else r[:lanes] for r in padded)
    held: list[torch.Tensor] = []  # every tensor the inputs wrap, kept until they are released (DrJitArrays.from_torch)
    with _DRJIT:
        inputs = tuple(_argument(xp, a, held) for a in args)
        key = (xp.name, fn, tuple(sorted(static.items())))  # Python values choose the code: one recording each (lanes.signature)
        frozen = _FROZEN.get(key)
        if frozen is None:
            frozen = _FROZEN[key] = xp.dr.freeze(_body(xp, fn, static), warn_after=1 << 30)
        if frozen is not _TRACED:
            try:
                out, widths, constants = frozen(inputs)
                if all(xp.dr.width(o) == lanes for o in out):
                    results = _results(xp, out, widths, constants, lanes, unstacked)
                    del inputs, out  # released here, before the tensors they wrap
                    return results
            except RuntimeError:  # a recording that failed
                pass
            # a replay that returned an array of another call's length (a point light's zero
            # emission, seen with two render workers; a recording whose lanes had a table's length
            # can mistake one for the other) or a recording that failed: this kind of call is
            # traced from now on
            _FROZEN[key] = _TRACED
        results = _results(xp, *_body(xp, fn, static)(inputs), lanes, unstacked)
        del inputs
        return results


#: calls on fewer lanes run on about this many (:func:`_padded`): small calls (the last bounces of a
#: chunk) replay one frozen kernel rather than being traced each (a few ms) or run as eager torch
#: (whose rounding differs: an image would depend on how its paths are split into chunks and
#: workers)
FREEZE_LANES = 4096


def _padded(args, lanes: int):
    """``args`` with every tensor of ``lanes`` rows padded by copies of its first row to
    ``FREEZE_LANES + lanes % 16`` rows (3-vectors stored by columns stay so), a Bool one by False
    (an ``active`` mask: padded lanes add nothing to :class:`Sums`). A flat table of
    ``lanes`` floats by coincidence only grows past its end, which no lane reads, and keeps its
    length's divisibility by the 4, 8 or 16 floats of its rows."""
    out = []
    for a in args:
        if isinstance(a, (tuple, list)):
            a = type(a)(_padded(a, lanes)) if isinstance(a, Columns) else tuple(_padded(a, lanes))
        elif isinstance(a, torch.Tensor) and a.ndim and a.shape[0] == lanes:
            pad = FREEZE_LANES + lanes % 16 - lanes
            if a.ndim == 2:
                a = torch.cat([a.t(), a.t()[:, :1].expand(-1, pad)], dim=1).t()  # by columns
            elif a.dtype == torch.bool:
                a = torch.cat([a, a.new_zeros(pad)])
            else:
                a = torch.cat([a, a[:1].expand(pad)])
        out.append(a)
    return out


def _results(xp, out, widths, constants, lanes: int, unstacked: bool = False) -> tuple[torch.Tensor, ...]:
    """The evaluated arrays ``out`` as torch tensors: (N,) each, and per k-tuple (N, k) by columns
    or (``unstacked``) :class:`Columns`; the outputs ``constants`` names (:func:`_constant`) filled
    with their value over ``lanes``."""
    xp.dr.sync_thread()
    arrays = iter(out)
    flat = [xp.to_torch(next(arrays)) if c is None else torch.full((lanes,), c[0], dtype=_DTYPES[c[1]], device="cuda" if xp.name.endswith("cuda") else "cpu") for c in constants]
    at = 0
    results = []
    for k in widths:
        if not k:
            results.append(flat[at])
        else:  # (N, k) by columns: no interleaving copy
            results.append(Columns(flat[at : at + k]) if unstacked else torch.stack(flat[at : at + k]).t())
        at += max(k, 1)
    return tuple(results)


#: per kind of call (the function and its static arguments), ``fn`` on ``xp`` traced once and
#: replayed (``drjit.freeze``): a call with other array sizes or values but the same static
#: arguments launches the recorded kernel without tracing the Python function again (tracing a
#: bounce costs about as much as running it on 2^16 lanes); :data:`_TRACED` for a kind of call
#: whose replays went wrong, traced on every call
_FROZEN: dict[tuple, object] = {}
_TRACED = object()
#: held by every compiled call: Dr.Jit's frozen functions are not safe across threads (a replay
#: beside another thread's recording crashed a fit's process; concurrent recordings failed), so
#: compiled calls run one at a time; the render workers' ray queries and torch work still overlap
#: them (measured: no slower than concurrent calls on the Cornell box and the specular box, 2
#: workers on 2 cores)
_DRJIT = threading.Lock()


def _body(xp, fn, static: dict):
    """``fn`` on ``xp`` as one kernel: ``inputs -> (the outputs' arrays, their widths)``.

    Its closure holds a partial and Dr.Jit's ``eval`` only: a frozen function traverses the
    variables its function closes over on every call, hashing what it finds, and it does so holding
    Dr.Jit's lock; a hash written in Python (:class:`~invrender.core.lanes.Material`'s) could then
    hand the GIL to another render worker that waits for that lock holding it (a deadlock seen
    with two workers). A partial's arguments are not traversed."""
    call, evaluate = functools.partial(fn, xp, **static), xp.dr.eval

    def body(args):
        out = call(*args)
        widths = [len(o) if isinstance(o, tuple) else 0 for o in out]
        flat = [c for o in out for c in (o if isinstance(o, tuple) else (o,))]
        constants = [_constant(xp, c) for c in flat]
        arrays = [c for c, k in zip(flat, constants) if k is None]
        evaluate(*arrays)  # one kernel
        return arrays, widths, constants

    return body


#: torch's dtype of an output constant's kind (:func:`_constant`)
_DTYPES = {"float": torch.float32, "int": torch.int32, "int64": torch.int64, "bool": torch.bool}


def _constant(xp, x):
    """(value, kind) of an output that is a literal, one value in every lane (no emitting shape
    hit: no emission), else None. A replay returns a literal with the width of the recording's
    call, not the replay's: such outputs are handed back as their value (a frozen function
    returns the Python values of its recording) and filled over the lanes."""
    if getattr(x, "state", None) != xp.dr.VarState.Literal:
        return None
    name = type(x).__name__
    value = x[0]
    if name.startswith("Bool"):
        return (bool(value), "bool")
    if name.startswith("Int64"):
        return (int(value), "int64")
    if name.startswith("UInt") or name.startswith("Int"):
        value = int(value) & 0xFFFFFFFF
        return (value - (1 << 32) if value >= 1 << 31 else value, "int")  # UInt as int32, as to_torch gives it
    return (float(value), "float")


def _lanes(args) -> int:
    """The lanes of a call: the rows of its 3-vector arguments ((N, 3) tensors and
    :class:`Columns`), else its longest array (tables are flat). One pass over the arguments,
    nested tuples included, without generators (it runs on every call: a Cornell render's 72
    calls walked their tables' tuples 6,000 times)."""
    rows, longest, stack = -1, 0, list(args)
    while stack:
        a = stack.pop()
        if isinstance(a, torch.Tensor):
            if a.ndim == 2:
                rows = max(rows, a.shape[0])
            elif a.ndim:
                longest = max(longest, a.shape[0])
        elif isinstance(a, Columns):
            rows = max(rows, a.lanes)
        elif isinstance(a, (tuple, list)):
            stack.extend(a)
    return rows if rows >= 0 else longest


def _argument(xp, a, held: list | None = None):
    if isinstance(a, Sums):
        return a.on(xp)
    if isinstance(a, Opaque):
        return xp.opaque(a.value)
    if isinstance(a, torch.Tensor):
        return xp.from_torch(a, lanes=True, held=held)
    if isinstance(a, (tuple, list)):
        return tuple(_argument(xp, x, held) for x in a)
    return a
