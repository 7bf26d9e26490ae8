"""The array interface the bounce is written against once, and its two evaluators.

A function written against it takes the namespace ``xp`` first and computes on 1-D arrays of one
length N (one lane per path), per component (a 3-vector is a tuple of three arrays), with masks
instead of data-dependent shapes:

- ``Float`` (float32), ``UInt`` (32 bits, read as unsigned) and ``Bool`` arrays, with Python's
  operators: ``+ - * /`` and comparisons on Float; ``* ^ & |`` on UInt (products wrap modulo 2^32);
  ``& | ~`` on Bool; Python numbers mix with arrays;
- :meth:`sqrt`, :meth:`cos`, :meth:`sin`, :meth:`abs`, :meth:`exp`, :meth:`log`, :meth:`floor`,
  :meth:`atan2`, :meth:`acos`, :meth:`tan`, :meth:`erf`, :meth:`erfinv`, :meth:`copysign`,
  :meth:`minimum`, :meth:`maximum`,
  :meth:`select` (``mask ? a : b``), :meth:`shr` (the logical right shift of a UInt),
  :meth:`bits24` (a UInt's low 24 bits as a Float), :meth:`u32` (a UInt constant),
  :meth:`gather_rows` (whole rows of 1, 2, 4, 8 or 16 floats of a table at UInt indices),
  :meth:`uint` (a Float holding an integer as a UInt), :meth:`full`, :meth:`opaque`;
- on UInt read as unsigned: :meth:`udiv`, :meth:`umod`, :meth:`ult` (``<``; Python's comparisons
  are signed on :data:`TORCH`'s int32), :meth:`float` (the nearest Float);
- :meth:`while_loop`: a loop whose lanes run until their condition fails (cycle walking);
- :meth:`scatter_add_rows`: the one side effect, rows of Floats added in float64 to a flat
  accumulator (:class:`~invrender.core.compiled.Sums`) at UInt row indices.

Tables are read by rows where they can be: Dr.Jit turns a row of a power-of-two width into packet
loads, where single-element gathers become the CPU's vector-gather instruction, which on the CPUs
measured here costs about 10 ns a lane (microcode mitigations), more than the rest of a bounce.

Two namespaces satisfy it:

- :data:`TORCH`: eager torch on the tensors' device; differentiable (autograd and forward-mode flow
  through every Float operation), so it is the reference the tests hold the other to. UInt arrays
  are int32 tensors with the same bits (an arithmetic shift and a mask make the logical shift).
- :func:`drjit_arrays`: Dr.Jit's ``llvm`` (CPU, SIMD across lanes) or ``cuda`` arrays. A function
  evaluated on them is traced, compiled by LLVM into one kernel (cached by Dr.Jit in memory and on
  disk) and frozen, so later calls replay the kernel without tracing
  (:mod:`invrender.core.compiled`, which carries torch tensors in and out by DLPack, without
  copies). Arrays of a call's width are made from its arrays (:meth:`full`), never from a width
  number, which a frozen kernel would keep.

The same counter-based bits come out of both (the integer hash is exact); floats agree to rounding.
"""

from __future__ import annotations

import glob
import os
import re
import threading

import torch

from invrender.backends import packages

#: the environment variable that picks the bounce's evaluator: ``drjit`` (default where importable) or ``torch``
ENV = "INVRENDER_BOUNCE"
CHOICES = ("drjit", "torch")

_U32 = 0xFFFFFFFF


def _signed(x: int) -> int:
    """A 32-bit unsigned value as the int32 with the same bits."""
    x &= _U32
    return x - (1 << 32) if x >= 1 << 31 else x


def _unsigned(x):
    """The unsigned value of a UInt held as int32 (as int64), or of a Python int."""
    return x.to(torch.int64) & _U32 if isinstance(x, torch.Tensor) else x & _U32


def _int32(x):
    """An unsigned 32-bit value (int64 tensor or Python int) as :data:`TORCH`'s UInt."""
    return (x - ((x >> 31) << 32)).to(torch.int32) if isinstance(x, torch.Tensor) else _signed(x)


#: the interface's elementwise functions: the library's own of the same name in both namespaces
#: (``copysign(a, b)``: ``|a|`` with the sign of ``b``)
ELEMENTWISE = ("sqrt", "cos", "sin", "abs", "exp", "log", "floor", "atan2", "acos", "tan", "erf", "erfinv", "copysign")


class Columns(tuple):
    """A 3-vector of N lanes kept as three (N,) tensors: a kernel's k-tuple output left unstacked
    (:func:`invrender.core.compiled.run` with ``unstacked``), which the next kernel and Embree's
    wrapper read as they are (stacking a kernel's 3-vectors into (N, 3) copies each once: 7% of a
    Cornell render's worker time); :meth:`stacked` for a consumer that takes (N, 3)."""

    __slots__ = ()

    @property
    def lanes(self) -> int:
        return self[0].shape[0]

    def stacked(self) -> torch.Tensor:
        """(N, k) stored by columns (a view of a (k, N) tensor)."""
        return torch.stack(tuple(self)).t()

    @staticmethod
    def of(x: torch.Tensor) -> Columns:
        """The columns of ``x`` (N, k) as views (without a copy where it is stored by columns)."""
        return Columns(x.t().unbind(0))

    def take(self, index: torch.Tensor) -> Columns:
        """The lanes at ``index`` (M,) int64."""
        return Columns(c.index_select(0, index) for c in self)

    def rows(self, a: int, b: int) -> Columns:
        """Lanes ``a`` to ``b - 1``."""
        return Columns(c[a:b] for c in self)


def take(x, index: torch.Tensor):
    """Lanes ``index`` (M,) int64 of ``x``: :class:`Columns`, a (N, k) tensor (one stored by
    columns kept so: the kernels' layout) or a (N,) one."""
    if isinstance(x, Columns):
        return x.take(index)
    if x.ndim == 2 and x.stride(0) == 1 and x.shape[1] > 1:
        return x.t().index_select(1, index).t()
    return x.index_select(0, index)


def stacked(x):
    """``x`` as a tensor: :class:`Columns` stacked to (N, k), anything else as it is."""
    return x.stacked() if isinstance(x, Columns) else x


class TorchArrays:
    """The array interface on torch tensors (module docstring): eager and differentiable."""

    name = "torch"

    @staticmethod
    def minimum(a, b):
        return torch.clamp_max(a, b) if not isinstance(b, torch.Tensor) else torch.minimum(a, b)

    @staticmethod
    def maximum(a, b):
        return torch.clamp_min(a, b) if not isinstance(b, torch.Tensor) else torch.maximum(a, b)

    @staticmethod
    def select(mask, a, b):
        return torch.where(mask, a, b)

    @staticmethod
    def shr(x, k: int):
        """``x >> k`` of 32-bit unsigned words held as int32."""
        return (x >> k) & ((1 << (32 - k)) - 1)

    @staticmethod
    def bits24(x):
        """(N,) Float: the low 24 bits of UInt ``x`` as a float in [0, 2^24)."""
        return (x & 0xFFFFFF).to(torch.float32)

    @staticmethod
    def u32(value: int):
        """A UInt constant (the int32 with its bits)."""
        return _signed(value)

    @staticmethod
    def gather_rows(table, index, width: int):
        """Rows ``index`` (N,) of ``table`` ((T * width,) float32 flat), as a ``width``-tuple of (N,)."""
        return tuple(table.view(-1, width).index_select(0, index if index.dtype in (torch.int32, torch.int64) else index.to(torch.int64)).unbind(1))

    @staticmethod
    def uint(x):
        """A Float holding non-negative integers (< 2^24) as a UInt."""
        return x.to(torch.int32)

    @staticmethod
    def udiv(a, b):
        """``a // b`` of UInt (or Python ints) read as unsigned."""
        return _int32(_unsigned(a) // _unsigned(b))

    @staticmethod
    def umod(a, b):
        """``a % b`` of UInt (or Python ints) read as unsigned."""
        return _int32(_unsigned(a) % _unsigned(b))

    @staticmethod
    def ult(a, b):
        """(N,) Bool ``a < b`` of UInt read as unsigned (the sign bits flipped, compared signed)."""
        return (a ^ -0x80000000) < (b ^ -0x80000000)

    @staticmethod
    def float(x):
        """A UInt (or Python int) read as unsigned, as the nearest Float."""
        u = _unsigned(x)
        return u.to(torch.float32) if isinstance(u, torch.Tensor) else float(u)

    @staticmethod
    def while_loop(state: tuple, args: tuple, cond, body) -> tuple:
        """Run ``state = body(*state, *args)`` on each lane while ``cond(*state, *args)`` holds:
        ``state`` a tuple of arrays, ``args`` arrays or numbers the loop reads. Eager: each round
        computes the lanes still running only (new tensors; the inputs are not written)."""
        state = [s.clone() for s in state]
        k = cond(*state, *args).nonzero().squeeze(1)
        while k.shape[0]:  # a synchronization per round
            sub = [a.index_select(0, k) if isinstance(a, torch.Tensor) and a.ndim else a for a in args]
            new = body(*(s.index_select(0, k) for s in state), *sub)
            for s, v in zip(state, new):
                s[k] = v
            k = k[cond(*new, *sub)]
        return tuple(state)

    @staticmethod
    def scatter_add_rows(target, values: tuple, index, active):
        """Add row ``values`` (a tuple of ``width`` (N,) Float, ``width`` a multiple of 16) of each
        ``active`` lane (N,) Bool, in float64, to row ``index`` (N,) of ``target`` ((R * width,)
        float64, written in place)."""
        k = active.nonzero().squeeze(1)
        rows = torch.stack(values, 1).index_select(0, k).to(torch.float64)
        target.view(-1, len(values)).index_add_(0, index.index_select(0, k).to(torch.int64), rows)

    @staticmethod
    def full(value, like):
        """An array of ``like``'s length filled with ``value``: Bool for a bool, Float for a float,
        UInt for an int (a UInt constant above 2^31 through :meth:`u32`)."""
        dtype = torch.bool if isinstance(value, bool) else torch.float32 if isinstance(value, float) else torch.int32
        return torch.full(like.shape, value, dtype=dtype, device=like.device)

    @staticmethod
    def opaque(value):
        """A UInt (an int) or Float (a float) scalar that changes from call to call (a bounce's
        salt, an emitter's share): a plain number here."""
        return value if isinstance(value, float) else _signed(value)

    @staticmethod
    def from_torch(t: torch.Tensor, lanes: bool, held: list | None = None):
        """An argument as the functions see it: (N, 3) lanes as a tuple of three columns."""
        return tuple(t.unbind(1)) if lanes and t.ndim == 2 else t

    @staticmethod
    def to_torch(x) -> torch.Tensor:
        """A result as torch: a k-tuple as (N, k), stored by columns (a view of a (k, N) tensor)."""
        return torch.stack(x).t() if isinstance(x, tuple) else x


for _f in ELEMENTWISE:
    setattr(TorchArrays, _f, staticmethod(getattr(torch, _f)))

#: the torch namespace (module docstring)
TORCH = TorchArrays()


class DrJitArrays:
    """The array interface on Dr.Jit arrays of one backend (``llvm`` or ``cuda``)."""

    def __init__(self, dr, backend):
        self.dr = dr
        self.name = f"drjit-{backend.__name__.rsplit('.', 1)[-1]}"
        self.Float, self.UInt, self.Bool, self.Int64, self._Int32 = backend.Float, backend.UInt32, backend.Bool, backend.Int64, backend.Int32
        self.Float64, self._Matrix4f64 = backend.Float64, backend.Matrix4f64
        self._rows = {2: backend.Array2f, 4: backend.Array4f}
        self._Matrix4f = backend.Matrix4f
        for f in ELEMENTWISE:
            setattr(self, f, getattr(dr, f))

    def minimum(self, a, b):
        return self.dr.minimum(a, b)

    def maximum(self, a, b):
        return self.dr.maximum(a, b)

    def select(self, mask, a, b):
        return self.dr.select(mask, a, b)

    def shr(self, x, k: int):
        return x >> k

    def bits24(self, x):
        return self.Float(x & 0xFFFFFF)

    def u32(self, value: int):
        return value & _U32

    def gather_rows(self, table, index, width: int):
        if width == 1:
            return (self.dr.gather(self.Float, table, index),)
        if width == 16:  # one 4 x 4 packet, row by row
            m = self.dr.gather(self._Matrix4f, table, index)
            return tuple(m[i][j] for i in range(4) for j in range(4))
        if width == 8:  # two packets of 4
            return sum((tuple(self.dr.gather(self._rows[4], table, index * 2 + k)) for k in range(2)), ())
        rows = self.dr.gather(self._rows[width], table, index)
        return tuple(rows[j] for j in range(width))

    def uint(self, x):
        return self.UInt(x)

    def udiv(self, a, b):
        return a // self._divisor(b)

    def umod(self, a, b):
        return a % self._divisor(b)

    def _divisor(self, b):
        """``b`` at least 1: LLVM's vector division traps on the zeros of a kernel's unused tail
        lanes (a divisor read per lane), where no lane of the array divides by zero."""
        return self.dr.maximum(b, 1) if isinstance(b, self.UInt) and self.dr.width(b) > 1 else b

    def ult(self, a, b):
        return a < b

    def float(self, x):
        return self.Float(x)

    def while_loop(self, state: tuple, args: tuple, cond, body) -> tuple:
        """A symbolic loop, compiled into the kernel (each lane stops on its own)."""
        return tuple(self.dr.while_loop(tuple(state), lambda *s: cond(*s, *args), lambda *s: tuple(body(*s, *args))))

    def scatter_add_rows(self, target, values: tuple, index, active):
        """(Rows of 16 float64 are packet scatter-adds: on the CPU, 7x faster than single ones.)"""
        k = len(values) // 16
        for j in range(k):
            v = values[16 * j : 16 * j + 16]
            packet = self._Matrix4f64(*([self.Float64(x) for x in v[4 * r : 4 * r + 4]] for r in range(4)))
            self.dr.scatter_reduce(self.dr.ReduceOp.Add, target, packet, index * k + j if k > 1 else index, active)

    def full(self, value, like):
        """(Computed from ``like``, so a frozen kernel gives it ``like``'s size whatever that is;
        ``min(|x|, 0)`` is 0 for every x, NaN included, and not a literal the tracer folds.)"""
        zero = self.dr.minimum(self.dr.abs(like if isinstance(like, self.Float) else self.Float(like)), 0.0)
        if isinstance(value, bool):
            return zero >= 0.0 if value else zero < 0.0
        if isinstance(value, float):
            return zero + value
        return self.UInt(zero) + (value & _U32)

    def opaque(self, value):
        """A UInt (an int) or Float (a float) scalar that changes from call to call, passed to the
        kernel as a value rather than compiled into it (one kernel for every bounce's salts)."""
        if isinstance(value, float):
            return self.dr.opaque(self.Float, value)
        return self.dr.opaque(self.UInt, value & _U32)

    def from_torch(self, t: torch.Tensor, lanes: bool, held: list | None = None):
        """A torch tensor as Dr.Jit arrays without a copy where it is contiguous: float32 as Float,
        int32 and int64 as UInt (the same low 32 bits), bool as Bool; (N, 3) lanes as three Floats.

        ``held`` receives every tensor the arrays wrap (copies made here included): the caller
        keeps them until the call's Dr.Jit arrays are released. A wrapped tensor that only Dr.Jit
        references is freed by Dr.Jit, possibly inside a kernel's launch, which releases the GIL
        holding Dr.Jit's lock; torch's deleter then waits for the GIL, while a render worker
        freeing a kernel's output (Dr.Jit's memory) holds the GIL and waits for that lock: a
        deadlock (seen with two workers)."""
        held = [] if held is None else held
        if lanes and t.ndim == 2:
            columns = tuple(t.t().contiguous())
            held.extend(columns)
            return tuple(self.Float(c) for c in columns)
        t = t.contiguous()
        if t.dtype not in (torch.float32, torch.int32, torch.int64, torch.bool):
            t = t.to(torch.float32)
        held.append(t)
        if t.dtype == torch.float32:
            return self.Float(t)
        if t.dtype == torch.int32:
            return self.dr.reinterpret_array(self.UInt, self._Int32(t))
        if t.dtype == torch.int64:  # the low 32 bits, converted inside the kernel
            return self.UInt(self.Int64(t))
        return self.Bool(t)

    def to_torch(self, x) -> torch.Tensor:
        """An evaluated array as a torch tensor sharing its memory: UInt as int32."""
        out = torch.from_dlpack(x)
        return out.view(torch.int32) if out.dtype == torch.uint32 else out


def _llvm_version(path: str) -> int:
    m = re.search(r"LLVM-?(\d+)", os.path.basename(path)) or re.search(r"llvm-(\d+)", path)
    return int(m.group(1)) if m else 0


_lock = threading.Lock()
_namespaces: dict[str, DrJitArrays | None] = {}


def drjit_arrays(device: torch.device) -> DrJitArrays | None:
    """The Dr.Jit namespace for ``device`` (``llvm`` on the CPU, ``cuda`` on CUDA), or None where
    Dr.Jit or its backend is missing (no libLLVM, no CUDA driver: a one-time note says so)."""
    kind = "cuda" if device.type == "cuda" else "llvm"
    with _lock:
        if kind not in _namespaces:
            _namespaces[kind] = _load(kind)
        return _namespaces[kind]


def _load(kind: str) -> DrJitArrays | None:
    if kind == "llvm" and "DRJIT_LIBLLVM_PATH" not in os.environ:
        found = sorted(glob.glob("/usr/lib/*/libLLVM-[0-9]*.so") + glob.glob("/usr/lib/llvm-*/lib/libLLVM*.so"), key=_llvm_version)
        if found:  # the newest system libLLVM (Dr.Jit's own search may stop at an older one)
            os.environ["DRJIT_LIBLLVM_PATH"] = found[-1]
    dr = packages.find("drjit")
    if dr is None:
        packages.note_once(f"drjit is not installed: the bounce runs as eager torch ({packages.install_hint('drjit')} for the compiled bounce)")
        return None
    try:
        backend = packages.find(f"drjit.{kind}")
        if backend is None or not dr.has_backend(getattr(dr.JitBackend, kind.upper() if kind == "cuda" else "LLVM")):
            raise RuntimeError(f"no {kind} backend")
    except Exception as e:  # no libLLVM (DRJIT_LIBLLVM_PATH) or no CUDA driver
        packages.note_once(f"Dr.Jit's {kind} backend is unavailable ({e}): the bounce runs as eager torch")
        return None
    dr.set_flag(dr.JitFlag.FastMath, False)  # IEEE arithmetic, op by op as torch rounds it: the same images
    return DrJitArrays(dr, backend)
