"""Embree's packet queries for the ``embree`` backend, through a small compiled wrapper.

embreex traces one ray per call; Embree's packet queries (``rtcIntersect16``, ``rtcOccluded16``)
test 16 rays against each node and triangle at once in AVX-512 lanes, and a wrapper that writes the
answers straight into torch tensors skips embreex's NumPy round trip. Measured on one path tracer's
batches (docs/scale.md#ray-queries), closest hits cost about half and shadow rays a third. The
packets are as wide as the CPU traces natively: 16 rays with AVX-512, 8 with AVX2 (where Embree
would emulate 16-ray packets, at 5-8% more a closest hit), else 4.

``$INVRENDER_EMBREE_CONFIG`` is handed to Embree's device as its configuration string
(``rtcNewDevice``): ``isa=avx2`` runs Embree's AVX2 kernels, and packets of 8, on a CPU with
AVX-512 too (a stand-in for an AVX2 machine); ``verbose=1`` prints what Embree chose.

The wrapper (``embree_packets.cpp`` beside this module) is compiled on first use against the
system's Embree 3 (Debian/Ubuntu: ``apt-get install g++ libembree-dev``) and cached in
``$INVRENDER_CACHE`` (default ``~/.cache/invrender``), one file per source, compiler and Embree
version. Where no compiler or Embree 3 is found, or with ``INVRENDER_EMBREE=embreex``, the backend
keeps embreex's single rays (:class:`invrender.backends.accel.EmbreeIntersector`), said once.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import hashlib
import os
import shutil
import subprocess
import tempfile
import threading
from pathlib import Path

import torch

from invrender.errors import ParameterError
from invrender import first_use

#: the environment variable choosing the embree backend's queries: ``packets`` (default) or ``embreex``
ENV = "INVRENDER_EMBREE"
MODES = ("packets", "embreex")
#: the environment variable holding Embree's device configuration string (empty: Embree's defaults)
CONFIG_ENV = "INVRENDER_EMBREE_CONFIG"
#: the instruction sets Embree 3's ``isa`` and ``max_isa`` settings name (another value would
#: silently give its SSE kernels)
ISAS = ("sse2", "sse4.2", "avx", "avx2", "avx512", "avx512skx")
SOURCE = Path(__file__).with_name("embree_packets.cpp")
INSTALL_HINT = "apt-get install g++ libembree-dev"

_lock = threading.Lock()
_loaded: list = []  # [ctypes.CDLL | None, why it is None]


def mode() -> str:
    """``$INVRENDER_EMBREE``: ``packets`` (the default) or ``embreex``; a one-line error otherwise."""
    value = os.environ.get(ENV, "packets") or "packets"
    if value not in MODES:
        raise ParameterError(f"{ENV}={value!r} is not one of {', '.join(MODES)}")
    return value


def config() -> str:
    """``$INVRENDER_EMBREE_CONFIG``, Embree's device configuration (``key=value`` settings separated
    by commas; empty: the defaults); a one-line error for a setting that is not ``key=value`` or an
    ``isa``/``max_isa`` Embree does not know (:data:`ISAS`)."""
    value = os.environ.get(CONFIG_ENV, "").strip()
    for setting in filter(None, (s.strip() for s in value.split(","))):
        key, eq, choice = (part.strip() for part in setting.partition("="))
        if not eq or not key or not choice:
            raise ParameterError(f"{CONFIG_ENV}={value!r}: {setting!r} is not key=value (Embree's device settings, e.g. isa=avx2)")
        if key in ("isa", "max_isa") and choice not in ISAS:
            raise ParameterError(f"{CONFIG_ENV}={value!r}: {key} {choice!r} is not one of {', '.join(ISAS)}")
    return value


def cache_dir() -> Path:
    """Where compiled wrappers are kept: ``$INVRENDER_CACHE`` or ``~/.cache/invrender``."""
    root = os.environ.get("INVRENDER_CACHE") or os.path.join(os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "invrender")
    return Path(root) / "native"


def library() -> tuple[ctypes.CDLL | None, str]:
    """The loaded wrapper, built on first use (once per process), or None and the reason why not."""
    with _lock:
        if not _loaded:
            _loaded.extend(_build_and_load())
        return _loaded[0], _loaded[1]


def _build_and_load() -> tuple[ctypes.CDLL | None, str]:
    compiler = os.environ.get("CXX") or shutil.which("c++") or shutil.which("g++") or shutil.which("clang++")
    embree = ctypes.util.find_library("embree3")
    if compiler is None:
        return None, "no C++ compiler found"
    if embree is None:
        return None, "Embree 3 (libembree3) is not installed"
    try:
        version = subprocess.run([compiler, "--version"], capture_output=True, text=True, timeout=30).stdout
    except (OSError, subprocess.SubprocessError) as error:
        return None, f"the C++ compiler {compiler} does not run ({error})"
    source = SOURCE.read_bytes()
    flags = ["-O3", "-std=c++17", "-shared", "-fPIC"]
    key = hashlib.sha256(source + version.encode() + embree.encode() + " ".join(flags).encode()).hexdigest()[:16]
    target = cache_dir() / f"embree_packets-{key}.so"
    if not target.exists():
        try:
            target.parent.mkdir(parents=True, exist_ok=True)
            with tempfile.TemporaryDirectory(dir=target.parent) as tmp, first_use.compiling("the Embree packet wrapper", cached=False):
                built = Path(tmp) / target.name
                run = subprocess.run([compiler, *flags, str(SOURCE), "-o", str(built), "-lembree3"], capture_output=True, text=True, timeout=300)
                if run.returncode != 0:
                    first = next((line for line in run.stderr.splitlines() if "error" in line), run.stderr.strip()[:200])
                    return None, f"the wrapper does not compile ({first.strip()})"
                os.replace(built, target)  # atomic: concurrent processes build the same file
        except (OSError, subprocess.SubprocessError) as error:
            return None, f"the wrapper cannot be built in {target.parent} ({error})"
    try:
        lib = ctypes.CDLL(str(target))
    except OSError as error:
        return None, f"the wrapper does not load ({error})"
    p, i64 = ctypes.c_void_p, ctypes.c_int64
    lib.ir_embree_new.restype = p
    lib.ir_embree_new.argtypes = [p, i64, ctypes.c_char_p, ctypes.c_char_p, i64]
    lib.ir_embree_lanes.restype = i64
    lib.ir_embree_lanes.argtypes = [p]
    lib.ir_embree_free.argtypes = [p]
    lib.ir_embree_intersect.argtypes = [p, p, p, p, i64, p, p, p, i64, i64, p, p, p, p]
    lib.ir_embree_occluded.argtypes = [p, p, p, p, i64, p, p, p, i64, p, i64, p]
    lib.ir_embree_hits.restype = i64
    lib.ir_embree_hits.argtypes = [p, p, p, p, i64, p, p, p, i64, i64, p, p, p, p, p, p, p, p]
    return lib, ""


class PacketScene:
    """One triangle scene in Embree, queried in packets of :attr:`lanes` rays; tensors in and out on
    the CPU."""

    def __init__(self, lib: ctypes.CDLL, corners: torch.Tensor):
        """``corners``: (T, 3, 3) triangle corners. On a device configured by :func:`config`: a
        device Embree refuses (a setting it cannot take, an ``isa`` this CPU lacks) is a one-line
        :class:`~invrender.errors.ParameterError` naming the variable."""
        self._lib = lib
        settings = config()
        corners = corners.detach().to("cpu", torch.float32).contiguous()
        error = ctypes.create_string_buffer(256)
        self._handle = lib.ir_embree_new(corners.data_ptr(), corners.shape[0], settings.encode(), error, len(error))
        if not self._handle:
            if settings:
                raise ParameterError(f"{CONFIG_ENV}={settings!r}: {error.value.decode()}")
            raise RuntimeError(error.value.decode())
        #: the rays a packet holds: the widest Embree traces natively on this CPU (16, 8 or 4)
        self.lanes = int(lib.ir_embree_lanes(self._handle))

    def __del__(self):
        if getattr(self, "_handle", None):
            self._lib.ir_embree_free(self._handle)
            self._handle = None

    def intersect(self, o, d, out: tuple[torch.Tensor, ...]) -> None:
        """Closest hits of rays ``o``, ``d`` on the CPU, each (N, 3) float32 of any strides (rows
        or columns: the wrapper reads through them) or three contiguous (N,) float32 columns,
        written into ``out`` = (t (N,) float32 (inf: a miss), prim (N,) int64 (-1: a miss), u, v
        (N,) float32), contiguous."""
        t, prim, u, v = out
        self._lib.ir_embree_intersect(self._handle, *_strided(o), *_strided(d), t.shape[0], t.data_ptr(), prim.data_ptr(), u.data_ptr(), v.data_ptr())

    def hits(self, o, d, out: tuple[torch.Tensor, ...], gone: torch.Tensor | None, alive: torch.Tensor | None = None) -> tuple[int, int]:
        """:meth:`intersect` compacted to the rays that hit: returns their count H and the count M
        of the rays that missed, and writes ``out`` = (index, t, prim, u, v), each (N,) contiguous
        (int64, float32, int64, float32, float32), in their first H entries: the rays that hit in
        order and their hits; with ``gone`` (N,) int64, the rays that missed into its first M
        entries, in order. With ``alive`` (N,) bool contiguous, the rays where it is False are not
        traced and neither hit nor miss."""
        index, t, prim, u, v = out
        missed = ctypes.c_int64(0)
        h = self._lib.ir_embree_hits(self._handle, *_strided(o), *_strided(d), t.shape[0], None if alive is None else alive.data_ptr(), index.data_ptr(), t.data_ptr(), prim.data_ptr(),
                                     u.data_ptr(), v.data_ptr(), None if gone is None else gone.data_ptr(), ctypes.byref(missed))  # fmt: skip
        return h, missed.value

    def occluded(self, o, d, tmax: torch.Tensor, out: torch.Tensor) -> None:
        """Into ``out`` (N,) bool: does something lie along each ray strictly before ``tmax`` (N,)
        float32 contiguous? False where ``tmax`` is not positive (not traced)."""
        self._lib.ir_embree_occluded(self._handle, *_strided(o), *_strided(d), tmax.data_ptr(), tmax.shape[0], out.data_ptr())


def _strided(x) -> tuple[int, int, int, int]:
    """Rays' origins or directions as the wrapper reads them: each component's data pointer and the
    stride along the rays in floats, of a (N, 3) float32 tensor or of three (N,) columns."""
    if isinstance(x, torch.Tensor):
        base, comp = x.data_ptr(), 4 * x.stride(1)
        return base, base + comp, base + 2 * comp, x.stride(0)
    if any(c.stride(0) != 1 for c in x):
        raise ValueError("Embree's wrapper reads columns that are contiguous")
    return x[0].data_ptr(), x[1].data_ptr(), x[2].data_ptr(), 1
