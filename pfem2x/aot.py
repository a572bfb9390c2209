"""The particle kernels compiled ahead of time: runs that never import numba.

numba compiles the kernels of :data:`SOURCES` on first use and caches them
(:mod:`pfem2x.jit`); loading them back still costs a process about half a second
(importing numba, its registries, one library per kernel). ``make setup``
(``python -m pfem2x.jit``) therefore also compiles every specialisation the
warm-up calls into one extension module with numba's ahead-of-time compiler
(:func:`pfem2x.jit.build_ahead_of_time`; about half a minute, a C compiler
needed), next to numba's cache files, with a manifest of each kernel's argument
types and a hash of the sources.

In a run, the kernel modules' ``@njit`` (:func:`njit`) then makes each kernel a
:class:`Kernel`: a call whose arguments have exactly the types of a compiled
specialisation (dtypes, dimensions, layout, read-only flag, scalar types, as
numba's own dispatch would see them) runs the compiled code, which is the code
numba would have run; any other call, or a keyword argument, makes the process
load numba and run the kernel through its JIT as before (:func:`materialize`), and
the kernel's name is recorded (:func:`jit_kernels`, ``summary.json``). The module
is used only while its hash matches the sources, numba's version and Python's;
``PFEM2X_KERNELS=numba`` in the environment always takes numba's JIT.
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib.metadata
import importlib.util
import json
import os
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

_PKG = Path(__file__).resolve().parent
KERNELS = _PKG / "particles" / "_kernels.py"
#: The modules of numba kernels and the warm-up (:mod:`pfem2x.jit`, which decides which
#: kernels are called with which argument types): numba's cache is cold after a change
#: of any of them.
JIT_SOURCES = (
    KERNELS,
    _PKG / "physics" / "flow" / "_kernels.py",
    _PKG / "physics" / "flow" / "_load_kernels.py",
    _PKG / "jit.py",
)
#: Every file whose change makes the compiled module stale: those and this module.
SOURCES = (*JIT_SOURCES, Path(__file__).resolve())
#: This Python's tag in the names of cache files.
TAG = f"py{sys.version_info[0]}{sys.version_info[1]}"

#: The environment variable that chooses the kernels: ``numba`` (numba's JIT always)
#: or anything else / unset (the compiled module when it is current).
ENV = "PFEM2X_KERNELS"
#: The extension module's name (its ``PyInit_`` symbol).
NAME = "pfem2x_kernels_aot"
#: The manifest next to the module (one per Python version): its file, the sources'
#: hash, the kernels' types.
MANIFEST = f"{NAME}.{TAG}.json"

KERNEL_MODULES = (
    "pfem2x.particles._kernels",
    "pfem2x.physics.flow._kernels",
    "pfem2x.physics.flow._load_kernels",
)


def cache_dir() -> Path:
    """The folder that holds the kernels' numba cache files (numba's own choice).

    Returns
    -------
    Path
        Below ``NUMBA_CACHE_DIR`` when that is set; else
        ``pfem2x/particles/__pycache__`` when it is writable (a clone or an
        editable install); else below the user's cache folder.
    """
    src = KERNELS.parent
    # numba's name for a source folder in a cache folder of its own
    sub = f"{src.name}_{hashlib.sha1(str(src).encode()).hexdigest()}"
    override = os.environ.get("NUMBA_CACHE_DIR")
    if override:
        return Path(override) / sub
    tree = src / "__pycache__"
    if os.access(tree if tree.exists() else src, os.W_OK):
        return tree
    home = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(home) / "numba" / sub


def numba_version() -> str:
    """The installed numba's version, from its package metadata (numba is not imported)."""
    try:
        return importlib.metadata.version("numba")
    except importlib.metadata.PackageNotFoundError:
        return "unknown"


def source_hash() -> str:
    """The hash the compiled module must carry: sources, numba and Python versions."""
    h = hashlib.sha1()
    for p in SOURCES:
        h.update(p.read_bytes())
    h.update(f"{numba_version()} {sys.version} {sys.platform}".encode())
    return h.hexdigest()


# ---------------------------------------------------------------- argument checks
def _is_array(x: Any, dtype: np.dtype, ndim: int, layout: str, readonly: bool) -> bool:
    """Whether numba would type ``x`` as ``Array(dtype, ndim, layout, readonly)``."""
    if type(x) is not np.ndarray or x.ndim != ndim or x.dtype != dtype:
        return False
    f = x.flags
    if not f.aligned or f.writeable == readonly:
        return False
    if f.c_contiguous:
        return layout == "C"
    return layout == ("F" if f.f_contiguous else "A")


_INT_RANGE = {"int64": (-(2**63), 2**63), "uint64": (2**63, 2**64)}


def _is_scalar(x: Any, name: str) -> bool:
    """Whether numba would type the scalar ``x`` as ``name`` (a numpy type name)."""
    t = type(x)
    if name == "bool":
        return t is bool or t is np.bool_
    if name == "float64" and t is float:
        return True
    if t is int and name in _INT_RANGE:  # numba: int64, or uint64 beyond its range
        lo, hi = _INT_RANGE[name]
        return lo <= x < hi
    return t is getattr(np, name, None)


def _is_tuple(x: Any, typename: str | None, checks: list[Callable[[Any], bool]]) -> bool:
    if typename is None:
        if type(x) is not tuple:
            return False
    elif not isinstance(x, tuple) or type(x).__name__ != typename:
        return False
    return len(x) == len(checks) and all(c(v) for c, v in zip(checks, x, strict=True))


def _check(spec: list) -> Callable[[Any], bool]:
    """The test of one argument against its manifest entry."""
    kind = spec[0]
    if kind == "array":
        dt, nd, layout, ro = np.dtype(spec[1]), int(spec[2]), str(spec[3]), bool(spec[4])
        return lambda x: _is_array(x, dt, nd, layout, ro)
    if kind == "scalar":
        name = str(spec[1])
        return lambda x: _is_scalar(x, name)
    if kind == "tuple":
        typename, items = spec[1], [_check(s) for s in spec[2]]
        return lambda x: _is_tuple(x, typename, items)
    raise ValueError(f"unknown argument kind {kind!r} in {MANIFEST}")


def _signature_check(specs: list) -> Callable[[tuple], bool]:
    checks = [_check(s) for s in specs]
    n = len(checks)
    return lambda args: len(args) == n and all(c(v) for c, v in zip(checks, args, strict=True))


# ---------------------------------------------------------------- the kernels
class Kernel:
    """A kernel of the compiled module, with numba's JIT for any other call.

    Parameters
    ----------
    func:
        The kernel's Python source function (numba compiles it on a fallback).
    options:
        Its ``@njit`` options.
    variants:
        ``(check, compiled)`` pairs: a call whose arguments pass ``check`` runs
        ``compiled``.
    """

    def __init__(self, func: Callable, options: dict, variants: list) -> None:
        self.py_func = func
        self.options = options
        self.variants = variants
        self.dispatcher: Any = None
        self.__name__ = func.__name__
        self.__qualname__ = func.__qualname__
        self.__module__ = func.__module__
        self.__doc__ = func.__doc__
        _STATE["kernels"].append(self)

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        if not kwargs and not _STATE["numba"]:
            for check, compiled in self.variants:
                if check(args):
                    return compiled(*args)
        if self.dispatcher is None:
            materialize()
        _STATE["jit"].add(self.__name__)
        if _STATE["numba"]:
            return self.dispatcher(*args, **kwargs)
        with _numba_globals():  # (numba may compile it now: the kernels it calls)
            return self.dispatcher(*args, **kwargs)


_STATE: dict[str, Any] = {
    "table": None,
    "loaded": False,
    "kernels": [],
    "jit": set(),
    "numba": False,
    "swapped": False,
}
#: Called (no arguments) when a run first falls back to numba (:func:`materialize`).
on_numba: list[Callable[[], Any]] = []


def _load() -> dict[str, list] | None:
    """The compiled kernels by qualified name (``None``: none, or not current)."""
    if _STATE["loaded"]:
        return _STATE["table"]
    _STATE["loaded"] = True
    if os.environ.get(ENV, "") == "numba":
        return None
    try:
        folder = cache_dir()
        manifest = json.loads((folder / MANIFEST).read_text())
        if manifest.get("hash") != source_hash():
            return None
        spec = importlib.util.spec_from_file_location(NAME, folder / manifest["file"])
        if spec is None or spec.loader is None:
            return None
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        table = {
            qual: [(_signature_check(args), getattr(module, export)) for export, args in variants]
            for qual, variants in manifest["kernels"].items()
        }
    except (OSError, ValueError, KeyError, TypeError, ImportError, AttributeError):
        return None
    _STATE["table"] = table
    return table


def active() -> bool:
    """Whether the kernels run from the compiled module (it is there and current)."""
    return _load() is not None


def jit_kernels() -> list[str]:
    """The kernels this process ran through numba's JIT although compiled ahead of time."""
    return sorted(_STATE["jit"])


def njit(*args: Any, **options: Any) -> Any:
    """numba's ``njit`` for the kernel modules, or a :class:`Kernel` (:func:`active`).

    Used as ``@njit(...)`` like numba's: without a current compiled module, numba's
    own decorator (numba imported as before).
    """
    if len(args) == 1 and callable(args[0]) and not options:
        return njit()(args[0])
    table = _load()
    if table is None:
        import numba  # noqa: PLC0415

        return numba.njit(*args, **options)

    def wrap(func: Callable) -> Kernel:
        return Kernel(func, options, table.get(f"{func.__module__}.{func.__qualname__}", []))

    return wrap


def use_numba() -> None:
    """Every kernel through numba's JIT from now on in this process (the warm-up's
    exercise, which fills numba's cache); nothing to do without a compiled module."""
    if _STATE["kernels"]:
        _STATE["numba"] = True
        materialize()
        _swap_globals(to_numba=True)


def materialize() -> None:
    """Import numba and give every kernel its JIT dispatcher (once per kernel).

    The kernel modules keep their :class:`Kernel` objects (the compiled module
    first); numba sees the dispatchers while it runs a kernel
    (:func:`_numba_globals`).
    """
    import numba  # noqa: PLC0415

    for k in _STATE["kernels"]:
        if k.dispatcher is None:
            k.dispatcher = numba.njit(**k.options)(k.py_func)
    hooks = list(on_numba)
    on_numba.clear()
    for hook in hooks:
        hook()


def _swap_globals(to_numba: bool) -> None:
    """The kernel modules' kernels as numba's dispatchers (or back as :class:`Kernel`)."""
    back = {id(k.dispatcher): k for k in _STATE["kernels"] if k.dispatcher is not None}
    for name in KERNEL_MODULES:
        module = sys.modules.get(name)
        for key, value in list(vars(module).items()) if module else ():
            if to_numba and isinstance(value, Kernel) and value.dispatcher is not None:
                setattr(module, key, value.dispatcher)
            elif not to_numba and id(value) in back:
                setattr(module, key, back[id(value)])


@contextlib.contextmanager
def _numba_globals() -> Iterator[None]:
    """While numba runs a kernel: the kernels it calls are dispatchers in their modules'
    globals, as numba needs to compile a caller (a nested use keeps the outer one's)."""
    if _STATE["swapped"]:
        yield
        return
    _STATE["swapped"] = True
    _swap_globals(to_numba=True)
    try:
        yield
    finally:
        _swap_globals(to_numba=False)
        _STATE["swapped"] = False


def is_current() -> bool:
    """Whether the compiled module is there and matches the sources (no loading)."""
    folder = cache_dir()
    try:
        manifest = json.loads((folder / MANIFEST).read_text())
        return manifest["hash"] == source_hash() and (folder / manifest["file"]).is_file()
    except (OSError, ValueError, KeyError, TypeError):
        return False
