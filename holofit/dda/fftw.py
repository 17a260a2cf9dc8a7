"""FFTW, called directly: plans made through its C interface, executed from numba kernels.

The DDA convolution (:mod:`holofit.dda.convolution`) runs its transforms slab by slab inside one
compiled kernel, so it needs FFTW's plans as plain pointers and ``fftw_execute`` as a function
it can call without going back to Python. This module

* finds the FFTW libraries: the copies bundled with pyFFTW (found through the symbols of
  pyFFTW's extension module, which links them), else the system's ``libfftw3`` /
  ``libfftw3f``; ``HOLOFIT_FFT=numpy`` disables FFTW (numpy's pocketfft is used instead);
* makes plans with FFTW's guru interface (one transform length, any number of batch
  dimensions, in place or out of place) on the caller's buffers, with ``FFTW_MEASURE``;
* keeps FFTW's wisdom (its measured plans) in
  ``$XDG_CACHE_HOME/holofit/fftw-wisdom-<fftw version>-<precision>.txt``, so measuring is a
  one-time cost per machine and transform shape (like numba's compiled kernels);
* exposes :func:`execute`, a numba intrinsic calling ``fftw_execute(plan)`` through its
  address.

Plans stay valid while the arrays they were made on live; :class:`Plan` keeps references to
them and destroys the FFTW plan when it is garbage collected.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import os
import tempfile
import threading
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from llvmlite import ir
from numba import types
from numba.extending import intrinsic
from numpy.typing import DTypeLike, NDArray

__all__ = [
    "BACKWARD",
    "FORWARD",
    "Plan",
    "aligned_zeros",
    "available",
    "execute",
    "execute_address",
    "plan_dft",
]

FORWARD = -1
BACKWARD = 1
_MEASURE = 0
_PATIENT = 1 << 5
_ALIGN = 64  # bytes; FFTW's SIMD code needs 16 (32 for AVX single precision)

_LOCK = threading.Lock()  # FFTW's planner is not thread safe


class _IODim(ctypes.Structure):
    _fields_ = [("n", ctypes.c_int), ("is_", ctypes.c_int), ("os", ctypes.c_int)]


@dataclass
class _Library:
    """The few FFTW entry points holofit uses, for one precision."""

    prefix: str
    handle: ctypes.CDLL
    precision: str

    def __post_init__(self) -> None:
        f = self.fn
        self.plan_guru_dft = f("plan_guru_dft", ctypes.c_void_p,
                               [ctypes.c_int, ctypes.POINTER(_IODim), ctypes.c_int,
                                ctypes.POINTER(_IODim), ctypes.c_void_p, ctypes.c_void_p,
                                ctypes.c_int, ctypes.c_uint])
        self.destroy_plan = f("destroy_plan", None, [ctypes.c_void_p])
        self.execute = f("execute", None, [ctypes.c_void_p])
        self.export_wisdom_to_string = f("export_wisdom_to_string", ctypes.c_void_p, [])
        self.import_wisdom_from_string = f("import_wisdom_from_string", ctypes.c_int,
                                           [ctypes.c_char_p])
        self.free = f("free", None, [ctypes.c_void_p])
        try:  # ``const char fftw_version[]``: an array, read from its address
            first = ctypes.c_char.in_dll(self.handle, self.prefix + "version")
            self.version = ctypes.string_at(ctypes.addressof(first))
        except ValueError:  # pragma: no cover - very old FFTW
            self.version = b"fftw-3"
        self.wisdom_loaded = False

    def fn(self, name: str, restype, argtypes):
        func = getattr(self.handle, self.prefix + name)
        func.restype = restype
        func.argtypes = argtypes
        return func

    # -- wisdom ---------------------------------------------------------------------------
    def wisdom_file(self) -> Path:
        base = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache"))
        version = (self.version or b"fftw").decode(errors="replace").replace("/", "_")
        return base / "holofit" / f"fftw-wisdom-{version}-{self.precision}.txt"

    def export_wisdom(self) -> bytes:
        ptr = self.export_wisdom_to_string()
        if not ptr:
            return b""
        try:
            return ctypes.string_at(ptr)
        finally:
            self.free(ptr)

    def load_wisdom(self) -> None:
        if self.wisdom_loaded:
            return
        self.wisdom_loaded = True
        with contextlib.suppress(OSError):
            self.import_wisdom_from_string(self.wisdom_file().read_bytes())

    def save_wisdom(self) -> None:
        path = self.wisdom_file()
        with contextlib.suppress(OSError):
            path.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".part")
            with os.fdopen(fd, "wb") as fh:
                fh.write(self.export_wisdom())
            os.replace(tmp, path)


def _candidate_handles(lib: str) -> list[ctypes.CDLL]:
    """Shared objects that may hold FFTW's symbols, best first."""
    handles = []
    try:  # pyFFTW links its own FFTW build: dlsym on its module finds the symbols
        import pyfftw.pyfftw as _ext

        handles.append(ctypes.CDLL(_ext.__file__))
    except (ImportError, OSError):  # pragma: no cover - depends on the installation
        pass
    name = ctypes.util.find_library(lib)
    if name:  # pragma: no cover - depends on the installation
        with contextlib.suppress(OSError):
            handles.append(ctypes.CDLL(name))
    return handles


_LIBS: dict[np.dtype, _Library | None] = {}


def _library(dtype: np.dtype) -> _Library | None:
    dtype = np.dtype(dtype)
    if dtype not in _LIBS:
        prefix, lib, precision = (("fftw_", "fftw3", "double") if dtype == np.complex128
                                  else ("fftwf_", "fftw3f", "single"))
        found = None
        for handle in _candidate_handles(lib):
            try:
                found = _Library(prefix, handle, precision)
                break
            except AttributeError:
                continue
        _LIBS[dtype] = found
    return _LIBS[dtype]


def available(dtype: DTypeLike = np.complex128) -> bool:
    """True if FFTW can be used for complex ``dtype`` (and ``HOLOFIT_FFT`` is not 'numpy')."""
    if os.environ.get("HOLOFIT_FFT", "").lower() == "numpy":
        return False
    if np.dtype(dtype) not in (np.complex128, np.complex64):
        return False
    return _library(np.dtype(dtype)) is not None


def aligned_zeros(shape: Sequence[int], dtype: DTypeLike) -> NDArray:
    """Zeroed C-contiguous array whose data start on a 64-byte boundary."""
    dt = np.dtype(dtype)
    n = int(np.prod(shape)) * dt.itemsize
    raw = np.zeros(n + _ALIGN, dtype=np.uint8)
    start = (-raw.ctypes.data) % _ALIGN
    return raw[start : start + n].view(dt).reshape(shape)


class Plan:
    """An FFTW plan on fixed arrays (kept alive with it)."""

    def __init__(self, pointer: int, library: _Library, arrays: tuple) -> None:
        self.pointer = int(pointer)
        self._library = library
        self._arrays = arrays

    def __call__(self) -> None:
        self._library.execute(self.pointer)

    def __del__(self) -> None:
        with contextlib.suppress(Exception):
            self._library.destroy_plan(self.pointer)


def plan_dft(dtype: DTypeLike, n: int, stride_in: int, stride_out: int,
             batch: Sequence[tuple[int, int, int]], array_in: NDArray, array_out: NDArray,
             direction: int, offset_in: int = 0, offset_out: int = 0,
             patient: bool = False) -> Plan:
    """Plan batched 1-D complex transforms of length ``n`` on ``array_in`` -> ``array_out``.

    Parameters
    ----------
    dtype : complex128 or complex64
        Precision.
    n : int
        Transform length.
    stride_in, stride_out : int
        Element strides along the transform.
    batch : sequence of (count, stride_in, stride_out)
        Batch dimensions (FFTW's ``howmany_dims``), strides in elements.
    array_in, array_out : ndarray
        The buffers (the same array for in-place transforms); their contents are destroyed
        by planning.
    direction : {FORWARD, BACKWARD}
        Sign of the exponent; FFTW does not normalise.
    offset_in, offset_out : int
        Element offsets of the first transform in the arrays.
    patient : bool
        Plan with ``FFTW_PATIENT`` instead of ``FFTW_MEASURE`` (a few tenths of a second more
        per small plan, once per machine thanks to the wisdom file; worth it for transforms
        executed thousands of times per product).
    """
    lib = _library(np.dtype(dtype))
    if lib is None:
        raise RuntimeError("FFTW is not available")
    for arr in (array_in, array_out):
        if arr.dtype != np.dtype(dtype) or not arr.flags.c_contiguous:
            raise ValueError("FFTW buffers must be C-contiguous arrays of the plan's dtype")
    dims = (_IODim * 1)(_IODim(n, stride_in, stride_out))
    howmany = (_IODim * max(len(batch), 1))(*[_IODim(*b) for b in batch])
    item = np.dtype(dtype).itemsize
    with _LOCK:
        lib.load_wisdom()
        before = lib.export_wisdom()
        ptr = lib.plan_guru_dft(1, dims, len(batch), howmany,
                                array_in.ctypes.data + offset_in * item,
                                array_out.ctypes.data + offset_out * item, direction,
                                _PATIENT if patient else _MEASURE)
        if not ptr:
            raise RuntimeError(f"FFTW could not plan a length-{n} transform with batch {batch}")
        if lib.export_wisdom() != before:
            lib.save_wisdom()
    return Plan(ptr, lib, (array_in, array_out))


def execute_address(dtype: DTypeLike) -> int:
    """Address of ``fftw_execute`` (or ``fftwf_execute``) for :func:`execute`."""
    lib = _library(np.dtype(dtype))
    if lib is None:
        raise RuntimeError("FFTW is not available")
    address = ctypes.cast(lib.execute, ctypes.c_void_p).value
    if address is None:
        raise RuntimeError("FFTW's execute function has a null address")
    return int(address)


@intrinsic
def execute(typingctx, function, plan):  # pragma: no cover - compiled
    """``execute(function_address, plan_pointer)``: call ``fftw_execute(plan)`` from numba."""
    sig = types.void(types.int64, types.int64)

    def codegen(context, builder, signature, args):
        void_ptr = ir.IntType(8).as_pointer()
        fnty = ir.FunctionType(ir.VoidType(), [void_ptr])
        fn = builder.inttoptr(args[0], fnty.as_pointer())
        builder.call(fn, [builder.inttoptr(args[1], void_ptr)])
        return context.get_dummy_value()

    return sig, codegen
