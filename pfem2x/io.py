"""Output: XDMF field time series, VTK particle clouds, CSV diagnostics, PNG snapshots.

Everything here is collective where it gathers and writes files from rank 0
only. ParaView opens ``fields.xdmf``, ``particles.pvd`` and the CSV directly.
"""

from __future__ import annotations

import csv
import importlib.util
import json
import os
import subprocess
import sys
import tempfile
import warnings
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:  # DOLFINx is imported lazily: `pfem2x study` uses this module without it
    from mpi4py import MPI

__all__ = [
    "CSVWriter",
    "FieldWriter",
    "ParticleWriter",
    "atomic_write_text",
    "chain_segments",
    "read_interface",
    "write_interface",
    "gather_p1",
    "png_snapshot",
    "pyvista_usable",
    "quiet_vtk",
    "write_json",
    "write_pvtp",
    "write_vtp",
]


def _umask() -> int:
    """The process's file mode creation mask (read without changing it where Linux tells)."""
    try:
        with open("/proc/self/status", encoding="ascii") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)  # elsewhere: set and restore (not atomic across threads)
    os.umask(mask)
    return mask


def atomic_write_text(path: str | os.PathLike, text: str) -> None:
    """Write a text file atomically (temporary file in the same folder, then rename).

    The file gets the mode of a file made by ``open(path, "w")``: ``0o666`` less the
    umask (the temporary file alone would keep ``0o600``).
    """
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            os.fchmod(f.fileno(), 0o666 & ~_umask())
            f.write(text)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_json(path: str | os.PathLike, data: Any) -> None:
    """Write JSON atomically (call on one rank)."""
    atomic_write_text(
        path, json.dumps(data, indent=2, sort_keys=False, default=_json_default) + "\n"
    )


def _json_default(o: Any) -> Any:
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(type(o))


class FieldWriter:
    """An XDMF time series of P1 functions (``fields.xdmf`` + ``.h5``)."""

    def __init__(self, comm: MPI.Comm, path: str | os.PathLike, mesh: Any):
        from pfem2x import compat  # noqa: PLC0415

        self.file = compat.xdmf_file(comm, str(path), "w")
        self.file.write_mesh(mesh)

    def write(self, functions: dict[str, Any], t: float) -> None:
        """Write every function at time ``t``."""
        for u in functions.values():
            self.file.write_function(u, t)

    def close(self) -> None:
        """Close the file."""
        self.file.close()


class CSVWriter:
    """Diagnostics over time, one row per step, written by rank 0 (flushed every row).

    ``keep_rows``: continue an existing file (a resumed run): keep its header and
    first ``keep_rows`` rows, drop the rest, append new rows.
    """

    def __init__(self, comm: MPI.Comm, path: str | os.PathLike, keep_rows: int | None = None):
        self.rank = comm.rank
        self.path = Path(path)
        self._f = None
        self._w: Any = None
        self._cols: list[str] | None = None
        if keep_rows is not None and self.rank == 0 and self.path.is_file():
            self._continue(keep_rows)

    def _continue(self, keep_rows: int) -> None:
        """Keep the header and the first ``keep_rows`` rows of an existing file, append after."""
        with open(self.path, newline="", encoding="utf-8") as f:
            lines = f.read().splitlines(keepends=True)
        if not lines:
            return
        atomic_write_text(self.path, "".join(lines[: 1 + keep_rows]))
        self._cols = next(csv.reader(lines[:1]))
        self._f = open(self.path, "a", newline="", encoding="utf-8")  # noqa: SIM115
        self._w = csv.DictWriter(self._f, fieldnames=self._cols, extrasaction="ignore")

    def write(self, row: dict[str, Any]) -> None:
        """Append a row (the first row fixes the columns; later new keys are dropped)."""
        if self.rank != 0:
            return
        if self._w is None:
            self._cols = list(row)
            self._f = open(self.path, "w", newline="", encoding="utf-8")  # noqa: SIM115
            self._w = csv.DictWriter(self._f, fieldnames=self._cols, extrasaction="ignore")
            self._w.writeheader()
        self._w.writerow({k: _fmt(row.get(k)) for k in self._cols})
        self._f.flush()

    def close(self) -> None:
        """Close the file."""
        if self._f is not None:
            self._f.close()


def _fmt(v: Any) -> Any:
    if isinstance(v, float):
        return f"{v:.10g}"
    return v


_VTK_TYPES = {
    np.dtype(np.float32): "Float32",
    np.dtype(np.float64): "Float64",
    np.dtype(np.int32): "Int32",
    np.dtype(np.int64): "Int64",
}


def _vtp_arrays(
    points: np.ndarray, fields: dict[str, np.ndarray], precision: str
) -> tuple[list[tuple[str, np.ndarray]], np.ndarray]:
    """The point data and the positions of a cloud as written (types, 3-vectors)."""
    if precision not in ("single", "double"):
        raise ValueError(f"precision must be 'single' or 'double', not {precision!r}")
    fdt = np.float32 if precision == "single" else np.float64

    def padded(a: np.ndarray, dtype: Any, below: int) -> np.ndarray:
        if a.ndim == 2 and below <= a.shape[1] < 3:  # ParaView wants 3-vectors
            out = np.zeros((a.shape[0], 3), dtype=dtype)
            out[:, : a.shape[1]] = a
            return out
        return np.ascontiguousarray(a, dtype=dtype)

    data = []
    for name, a in fields.items():
        a = np.asarray(a)
        data.append((name, padded(a, fdt if a.dtype.kind == "f" else np.int64, below=2)))
    pts = np.asarray(points)
    return data, padded(pts if pts.ndim == 2 else pts.reshape(-1, 1), fdt, below=1)


def _ncomp(a: np.ndarray) -> int:
    return 1 if a.ndim == 1 else a.shape[1]


def write_vtp(
    path: str | os.PathLike,
    points: np.ndarray,
    fields: dict[str, np.ndarray],
    precision: str = "double",
) -> None:
    """Write a VTK XML PolyData point cloud (appended raw binary) readable by ParaView.

    Parameters
    ----------
    path:
        The ``.vtp`` file.
    points:
        Positions, shape ``(n, gdim)`` (padded to 3 coordinates).
    fields:
        Point data: ``(n,)`` scalars or ``(n, k)`` vectors (2-vectors padded to 3).
    precision:
        ``"double"`` (Float64) or ``"single"`` (Float32) for positions and float
        fields; the vertex cells are Int32 (Int64 beyond 2**31 - 1 points).

    The XML header declares every array with its offset into the ``AppendedData``
    block, which holds each array's byte count (UInt64) and its bytes as they are
    in memory: nothing is encoded, and no copy of the whole file is made.
    """
    data, pts = _vtp_arrays(points, fields, precision)
    n = pts.shape[0]
    idt = np.int32 if n < 2**31 - 1 else np.int64
    blocks: list[np.ndarray] = []

    def decl(a: np.ndarray, name: str | None) -> str:
        offset = sum(8 + b.nbytes for b in blocks)  # a handful of arrays
        blocks.append(a)
        nm = f' Name="{name}"' if name else ""
        return (
            f'<DataArray type="{_VTK_TYPES[a.dtype]}"{nm} NumberOfComponents="{_ncomp(a)}" '
            f'format="appended" offset="{offset}"/>\n'
        )

    head = (
        '<?xml version="1.0"?>\n'
        '<VTKFile type="PolyData" version="1.0" byte_order="LittleEndian" '
        'header_type="UInt64">\n'
        f'<PolyData><Piece NumberOfPoints="{n}" NumberOfVerts="{n}" NumberOfLines="0" '
        'NumberOfStrips="0" NumberOfPolys="0">\n<PointData>\n'
        + "".join(decl(a, name) for name, a in data)
        + "</PointData>\n<Points>\n"
        + decl(pts, None)
        + "</Points>\n<Verts>\n"
        + decl(np.arange(n, dtype=idt), "connectivity")
        + decl(np.arange(1, n + 1, dtype=idt), "offsets")
        + '</Verts>\n</Piece></PolyData>\n<AppendedData encoding="raw">\n_'
    )
    with open(path, "wb") as fh:
        fh.write(head.encode())
        for a in blocks:
            fh.write(np.array([a.nbytes], dtype="<u8").tobytes())
            fh.write(a.ravel().view(np.uint8))
        fh.write(b"\n</AppendedData>\n</VTKFile>\n")


def write_pvtp(
    path: str | os.PathLike,
    pieces: list[str],
    points: np.ndarray,
    fields: dict[str, np.ndarray],
    precision: str = "double",
) -> None:
    """Write the parallel header (``.pvtp``) of ``.vtp`` pieces written by :func:`write_vtp`.

    ``pieces`` are the pieces' paths relative to ``path``'s folder; ``points`` and
    ``fields`` are any piece's arrays (of any length, also none: only their types
    and components are declared).
    """
    data, pts = _vtp_arrays(points, fields, precision)

    def decl(a: np.ndarray, name: str | None) -> str:
        nm = f' Name="{name}"' if name else ""
        return f'<PDataArray type="{_VTK_TYPES[a.dtype]}"{nm} NumberOfComponents="{_ncomp(a)}"/>\n'

    text = (
        '<?xml version="1.0"?>\n'
        '<VTKFile type="PPolyData" version="1.0" byte_order="LittleEndian" '
        'header_type="UInt64">\n<PPolyData GhostLevel="0">\n<PPointData>\n'
        + "".join(decl(a, name) for name, a in data)
        + "</PPointData>\n<PPoints>\n"
        + decl(pts, None)
        + "</PPoints>\n"
        + "".join(f'<Piece Source="{p}"/>\n' for p in pieces)
        + "</PPolyData>\n</VTKFile>\n"
    )
    Path(path).write_text(text)


class ParticleWriter:
    """A ``particles.pvd`` collection of the particle cloud over time.

    One process writes ``particles/step_NNNNNN.vtp``; on several ranks each rank
    writes its own particles (``particles/step_NNNNNN_rR.vtp``, nothing is
    gathered) and rank 0 the ``particles/step_NNNNNN.pvtp`` that joins them.
    """

    def __init__(self, comm: MPI.Comm, folder: str | os.PathLike, precision: str = "double"):
        self.comm = comm
        self.folder = Path(folder)
        self.precision = precision
        self.entries: list[tuple[float, str]] = []
        (self.folder / "particles").mkdir(parents=True, exist_ok=True)

    def write(
        self, positions: np.ndarray, fields: dict[str, np.ndarray], t: float, step: int
    ) -> None:
        """Write one time level (collective)."""
        comm, base = self.comm, f"step_{step:06d}"
        if comm.size == 1:
            rel = f"particles/{base}.vtp"
            write_vtp(self.folder / rel, positions, fields, self.precision)
        else:
            piece = f"{base}_r{comm.rank}.vtp"
            write_vtp(self.folder / "particles" / piece, positions, fields, self.precision)
            rel = f"particles/{base}.pvtp"
            if comm.rank == 0:
                pieces = [f"{base}_r{r}.vtp" for r in range(comm.size)]
                empty = {k: np.asarray(v)[:0] for k, v in fields.items()}  # types only
                write_pvtp(self.folder / rel, pieces, positions[:0], empty, self.precision)
        self.entries.append((t, rel))
        if comm.rank != 0:
            return
        body = "".join(f'<DataSet timestep="{tt:.10g}" file="{r}"/>\n' for tt, r in self.entries)
        atomic_write_text(
            self.folder / "particles.pvd",
            '<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1">\n<Collection>\n'
            + body
            + "</Collection>\n</VTKFile>\n",
        )


def chain_segments(segs: np.ndarray, tol: float = 1e-9) -> list[np.ndarray]:
    """Join segments ``(m, 2, 2)`` that share end points into polylines (output only).

    End points within ``tol`` times the extent (at least 1) are one point. Open ends
    start polylines first, so that open curves come out whole.

    Returns
    -------
    list of ``(k, 2)`` arrays, open or closed (first point repeated) polylines.
    """
    if len(segs) == 0:
        return []
    from pfem2x.particles._kernels import chain_walk  # noqa: PLC0415 (numba: on first use)

    pts = np.asarray(segs, dtype=float).reshape(-1, 2)
    scale = max(float(np.ptp(pts, axis=0).max()), 1.0)
    keys = np.round(pts / (tol * scale)).astype(np.int64)
    by_key = np.lexsort(keys.T[::-1])  # the points' ids: their keys' ranks
    k = keys[by_key]
    step = np.ones(len(k), dtype=np.int64)
    step[0] = 0
    step[1:] = (k[1:] != k[:-1]).any(axis=1)
    ids = np.empty(len(k), dtype=np.int64)
    ids[by_key] = np.cumsum(step)
    order, starts = chain_walk(ids.reshape(-1, 2), int(ids.max()) + 1)
    return np.split(pts[order], starts[1:-1])


def write_interface(comm: MPI.Comm, path: str | os.PathLike, segs: np.ndarray) -> None:
    """Gather interface segments to rank 0 and write them as polylines (CSV: line, x, y)."""
    parts = comm.gather(np.asarray(segs).reshape(-1, 2, 2), root=0)
    if comm.rank != 0:
        return
    lines = chain_segments(np.concatenate(parts) if parts else np.zeros((0, 2, 2)))
    rows = ["line,x,y"]
    for i, ln in enumerate(lines):  # (one format per polyline)
        rows.append((f"{i},%.9g,%.9g\n" * len(ln))[:-1] % tuple(ln.ravel().tolist()))
    atomic_write_text(path, "\n".join(rows) + "\n")


def read_interface(path: str | os.PathLike) -> list[np.ndarray]:
    """Read a polyline CSV written by :func:`write_interface`."""
    data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    if data.size == 0:
        return []
    line = data[:, 0].astype(int)
    cut = np.flatnonzero(np.diff(line)) + 1
    return [d[:, 1:] for d in np.split(data, cut)]


def gather_p1(u: Any) -> tuple[np.ndarray, np.ndarray] | tuple[None, None]:
    """Gather a scalar P1 function to rank 0 as per-cell vertex coordinates and values.

    Returns
    -------
    (coords, values)
        ``(ncells, nv, gdim)`` and ``(ncells, nv)`` on rank 0, ``(None, None)`` elsewhere.
    """
    mesh = u.function_space.mesh
    from pfem2x import compat  # noqa: PLC0415
    from pfem2x.mesh import geometry_table  # noqa: PLC0415

    tab = geometry_table(mesh)
    dofs = compat.dofmap_array(u.function_space)[: tab.num_cells_owned]
    coords = tab.coords[: tab.num_cells_owned]
    vals = u.x.array[dofs]
    comm = mesh.comm
    cs = comm.gather(coords, root=0)
    vs = comm.gather(vals, root=0)
    if comm.rank != 0:
        return None, None
    return np.concatenate(cs), np.concatenate(vs)


def png_snapshot(
    path: str | os.PathLike,
    u: Any,
    title: str = "",
    clim: tuple[float, float] | None = None,
    contour: float | None = None,
    label: str = "",
    segments: np.ndarray | None = None,
) -> None:
    """Render a scalar P1 field to PNG (collective; rank 0 writes).

    1D is a line plot, 2D a filled plot in the domain's aspect ratio with a
    colour bar (``label`` and the range) and the interface ``segments``
    (this rank's ``(m, 2, 2)``, e.g. the solver's ``interfaces()``) drawn on
    top; 1D with matplotlib, 2D with numpy and Pillow (:mod:`pfem2x.picture`);
    3D uses pyvista off-screen where it can
    render (probed once per installation, see :func:`pyvista_usable`).
    """
    coords, vals = gather_p1(u)
    segs = None
    if segments is not None:
        parts = u.function_space.mesh.comm.gather(np.asarray(segments).reshape(-1, 2, 2), root=0)
        segs = np.concatenate(parts) if parts else None
    if coords is None:
        return
    gdim = coords.shape[2]
    if gdim == 1:
        _png_1d(path, coords, vals, title)
    elif gdim == 2 or not pyvista_usable():
        from pfem2x.picture import png_2d  # noqa: PLC0415

        png_2d(path, coords, vals, title, clim, contour, label, segs)
    else:
        _png_pyvista(path, coords, vals, title, clim, contour)


_PYVISTA_OK: bool | None = None
_PROBE = """
import pyvista as pv
pl = pv.Plotter(off_screen=True, window_size=(64, 64))
pl.add_mesh(pv.Plane())
pl.screenshot(None, return_img=True)
"""


def quiet_vtk() -> None:
    """Silence VTK's warnings (e.g. "bad X server connection" on headless machines)."""
    try:
        import pyvista as pv  # noqa: PLC0415
        from vtkmodules.vtkCommonCore import vtkLogger, vtkObject  # noqa: PLC0415

        pv.OFF_SCREEN = True
        vtkObject.GlobalWarningDisplayOff()
        vtkLogger.SetStderrVerbosity(vtkLogger.VERBOSITY_OFF)
    except ImportError:  # pragma: no cover
        pass


def probe_cache_file() -> Path:
    """The file caching the pyvista probe (``$XDG_CACHE_HOME/pfem2x`` or ``~/.cache/pfem2x``)."""
    root = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(root) / "pfem2x" / "pyvista-probe.json"


def _probe_key() -> str:
    from importlib.metadata import PackageNotFoundError, version  # noqa: PLC0415

    vers = []
    for pkg in ("pyvista", "vtk"):
        try:
            vers.append(f"{pkg} {version(pkg)}")
        except PackageNotFoundError:
            vers.append(f"{pkg} ?")
    return f"{sys.executable} | {' | '.join(vers)}"


def pyvista_usable() -> bool:
    """Whether pyvista can render off-screen here.

    Without an OpenGL stack (EGL/OSMesa) VTK aborts the whole process, so the
    first render is tried in a child process, once per installation: the
    answer is cached in :func:`probe_cache_file`, keyed by the Python
    executable and the pyvista and VTK versions. ``PFEM2X_PNG_BACKEND``
    (``pyvista``, or ``pillow`` / ``matplotlib``: the 2D drawing) skips the probe.
    """
    global _PYVISTA_OK
    if _PYVISTA_OK is None:
        if os.environ.get("PFEM2X_PNG_BACKEND") in ("matplotlib", "pillow", "pyvista"):
            _PYVISTA_OK = os.environ["PFEM2X_PNG_BACKEND"] == "pyvista"
        elif importlib.util.find_spec("pyvista") is None:
            _PYVISTA_OK = False
        else:
            _PYVISTA_OK = _cached_probe()
    return _PYVISTA_OK


def _run_probe() -> bool | None:
    """Render once in a child process: whether it worked (``None``: it could not be run)."""
    try:
        res = subprocess.run(
            [sys.executable, "-c", _PROBE], capture_output=True, timeout=120, check=False
        )
    except (OSError, subprocess.TimeoutExpired):
        return None
    return res.returncode == 0


def _cached_probe() -> bool:
    path, key = probe_cache_file(), _probe_key()
    try:
        cache = json.loads(path.read_text(encoding="utf-8"))
        if isinstance(cache.get(key), bool):
            return cache[key]
    except (OSError, ValueError, AttributeError):
        cache = {}
    ok = _run_probe()
    if ok is None:
        return False  # not cached: a timeout may be a busy machine
    try:
        cache = cache if isinstance(cache, dict) else {}
        cache[key] = ok
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(path, json.dumps(cache, indent=1) + "\n")
    except OSError:
        pass
    return ok


def _png_1d(path: Any, coords: np.ndarray, vals: np.ndarray, title: str) -> None:
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    x = coords[:, :, 0].ravel()
    v = vals.ravel()
    order = np.argsort(x, kind="stable")
    fig, ax = plt.subplots(figsize=(7, 3.5))
    ax.plot(x[order], v[order], "-", lw=1.5)
    ax.set_xlabel("x")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _png_pyvista(
    path: Any, coords: np.ndarray, vals: np.ndarray, title: str, clim: Any, contour: float | None
) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        import pyvista as pv  # noqa: PLC0415

    quiet_vtk()
    nc, nv, gdim = coords.shape
    pts = np.zeros((nc * nv, 3))
    pts[:, :gdim] = coords.reshape(-1, gdim)
    cells = np.hstack([np.full((nc, 1), nv), np.arange(nc * nv).reshape(nc, nv)]).ravel()
    ctype = pv.CellType.TRIANGLE if nv == 3 else pv.CellType.TETRA
    grid = pv.UnstructuredGrid(cells, np.full(nc, ctype, dtype=np.uint8), pts)
    grid.point_data["value"] = vals.ravel()
    span = pts.max(axis=0) - pts.min(axis=0)
    aspect = span[1] / max(span[0], 1e-30) if gdim == 2 else 1.0
    if gdim == 2:  # the frame follows the domain's shape: longest side 1000 px
        w, h = (
            (1000, int(max(1000 * aspect, 250)))
            if aspect <= 1
            else (int(max(1000 / aspect, 250)), 1000)
        )
        h += 40  # title line
    else:
        w = h = 800
    pl = pv.Plotter(off_screen=True, window_size=(w, h))
    # No VTK scalar bar: with DOLFINx loaded, VTK 9.x wheels abort in its label
    # formatting (libstdc++ regex clash); the range goes into the title instead.
    pl.add_mesh(grid, scalars="value", cmap="viridis", clim=clim, show_scalar_bar=False)
    if contour is not None and gdim == 2:
        iso = grid.contour([contour], scalars="value")
        if iso.n_points:
            pl.add_mesh(iso, color="white", line_width=2)
    lo, hi = (float(vals.min()), float(vals.max())) if clim is None else clim
    pl.add_text(f"{title}   [{lo:.3g}, {hi:.3g}]", font_size=10)
    if gdim == 2:
        pl.view_xy()
        try:  # fill the frame (pyvista >= 0.38)
            pl.camera.tight(padding=0.03, view="xy")
        except (AttributeError, TypeError):
            pass
    pl.screenshot(str(path))
    pl.close()
