"""The small step API every solver exposes to the runner."""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np

from pfem2x.buffers import copy_into
from pfem2x.compat import MPI
from pfem2x.mesh import Domain
from pfem2x.scene import Scene, SceneError

__all__ = ["Diverged", "Solver", "require_finite", "require_finite_input"]


class Diverged(FloatingPointError):
    """The solution stopped being finite or physical; names the quantity."""


def require_finite(comm: MPI.Comm, what: str, values: np.ndarray) -> None:
    """Raise :class:`Diverged` ("``what`` is not finite") if ``values`` holds NaN/Inf on any rank.

    Collective: every rank enters the reduction and every rank raises.

    Parameters
    ----------
    comm
        The communicator of the ranks that share ``what``.
    what
        The quantity, as the message names it (e.g. ``"field T"``).
    values
        This rank's values.
    """
    bad = 0 if np.all(np.isfinite(values)) else 1
    if comm.allreduce(bad, op=MPI.MAX):
        raise Diverged(f"{what} is not finite")


def require_finite_input(
    comm: MPI.Comm,
    key: str,
    values: np.ndarray,
    coords: np.ndarray,
    where: str = "the whole domain",
) -> None:
    """Raise :class:`~pfem2x.scene.SceneError` naming ``key`` if ``values`` is not finite.

    For fields a scene key sets (an initial condition): NaN or Inf there is
    bad input, not a blow-up. The message gives the number of nodes and the
    first such node of the lowest rank that has one. Collective: every rank
    enters the reductions and every rank raises.

    Parameters
    ----------
    comm
        The communicator of the ranks that share the field.
    key
        The scene key (``section.key``) whose expression gave ``values``.
    values
        This rank's nodal values, one row (or value) per node of ``coords``.
    coords
        This rank's node coordinates (rows of at least 2 entries).
    where
        Where the expression must be finite (the message's advice).
    """
    vals = np.asarray(values).reshape(len(coords), -1)
    bad = ~np.all(np.isfinite(vals), axis=1)
    n_bad = int(comm.allreduce(int(bad.sum()), op=MPI.SUM))
    if n_bad == 0:
        return
    first = comm.allgather(coords[np.flatnonzero(bad)[0]] if bad.any() else None)
    xy = next(c for c in first if c is not None)
    first_at = ", ".join(f"{float(c):.6g}" for c in xy[: max(1, coords.shape[1])])
    raise SceneError(
        f"{key}: not finite at {n_bad} node(s) of the mesh, the first at ({first_at}); "
        f"give an expression that is finite on {where}"
    )


class Solver:
    """Base class of pfem2x solvers.

    A solver owns its fields and (optionally) a particle cloud. The runner
    owns time, output and printing: solvers never print.

    Subclasses implement :meth:`step` and may override the others.
    """

    #: short name, e.g. ``"transport-eulerian"``
    name = "solver"

    def __init__(self, scene: Scene, domain: Domain):
        self.scene = scene
        self.domain = domain
        self.comm: MPI.Comm = domain.comm
        #: wall seconds per phase, accumulated (``particles``, ``assembly``, ``solve``)
        self.timings: dict[str, float] = {"particles": 0.0, "assembly": 0.0, "solve": 0.0}
        #: the value each of the scene's ``"auto"`` keys took in this run (summary.json)
        self.auto_keys: dict[str, Any] = {}

    # -- time stepping ------------------------------------------------------
    def input_report(self, t0: float, t1: float) -> str:
        """Which of the scene's expressions are not finite in the step ``t0 -> t1`` (collective).

        Called after a divergence, to name the key when a scene expression (not the
        scheme) gave the NaN or Inf; ``""`` when none is (or the solver does not look).
        """
        return ""

    def max_velocity(self, t: float) -> float:
        """Largest speed on the mesh at time ``t`` (global); 0 when nothing moves."""
        return 0.0

    def step(self, t: float, dt: float) -> None:
        """Advance the solution from ``t`` to ``t + dt``."""
        raise NotImplementedError

    # -- output -------------------------------------------------------------
    def fields(self) -> dict[str, Any]:
        """Mesh functions to write, by name."""
        return {}

    def snapshot_field(self) -> tuple[str, Any]:
        """``(name, function)`` rendered in PNG snapshots (default: the first field)."""
        return next(iter(self.fields().items()))

    def time_label(self, t: float) -> str:
        """How time ``t`` is shown to users (e.g. in another time unit)."""
        return f"t = {t:.4g}"

    def interfaces(self) -> np.ndarray | None:
        """This rank's interface segments ``(m, 2, 2)``, or ``None`` without an interface."""
        return None

    def cloud(self) -> Any | None:
        """The particle cloud, if the solver has one."""
        return None

    def diagnostics(self, t: float) -> dict[str, float]:
        """Scalar diagnostics at time ``t`` (global values, same on all ranks)."""
        return {}

    def metrics(self, history: list[dict[str, float]]) -> dict[str, Any]:
        """Summary metrics from the diagnostics history (one dict per step)."""
        return {}

    def check_finite(self, t: float) -> None:
        """Raise :class:`Diverged` if any field holds NaN/Inf (collective)."""
        for name, u in self.fields().items():
            self.require_finite(f"field {name}", u.x.array)

    def require_finite(self, what: str, values: np.ndarray) -> None:
        """:func:`require_finite` on this solver's communicator (collective)."""
        require_finite(self.comm, what, values)

    @contextmanager
    def timer(self, key: str) -> Iterator[None]:
        """Add the wall time of the ``with`` block to ``timings[key]``.

        The keys are those ``summary.json`` reports: ``particles``, ``assembly``,
        ``solve`` (and ``reinit`` for the level set's re-distancing; ``diagnostics``
        and ``output`` for the runner's diagnostics and writers). A block inside
        another counts for its own key only: the outer one's time excludes it.
        """
        stack = self.__dict__.setdefault("_timer_inner", [])
        stack.append(0.0)  # the time of the blocks nested in this one
        t0 = time.perf_counter()
        try:
            yield
        finally:
            total = time.perf_counter() - t0
            inner = stack.pop()
            self.timings[key] = self.timings.get(key, 0.0) + (total - inner)
            if stack:
                stack[-1] += total

    def energy_scale(self) -> float:
        """A reference kinetic energy for the runner's energy guard (0: none)."""
        return 0.0

    def state(self, into: dict[str, np.ndarray] | None = None) -> dict[str, np.ndarray]:
        """Copies of the output fields and the particle cloud (the last good state).

        Lighter than :meth:`checkpoint`: what is needed to write the state for
        inspection, not to continue from it. ``into``: an earlier state, whose arrays
        take the copies where they have room (its values are then overwritten).
        """
        old = into or {}
        out = {}
        for k, u in self.fields().items():
            prev = old.get(f"field.{k}")
            a = u.x.array
            out[f"field.{k}"] = a.copy() if prev is None else copy_into(a, prev)
        cloud = self.cloud()
        if cloud is not None:
            out.update(_cloud_arrays(cloud, old))
        return out

    def restore(self, state: dict[str, np.ndarray]) -> None:
        """Put back arrays from :meth:`state` (or :meth:`checkpoint`)."""
        for k, u in self.fields().items():
            if f"field.{k}" in state:
                u.x.array[:] = state[f"field.{k}"]
        cloud = self.cloud()
        if cloud is not None and "cloud.x" in state:
            _restore_cloud(cloud, state)

    # -- checkpoint / restart ---------------------------------------------------
    #: the attributes a checkpoint stores (joined over the class hierarchy, see
    #: :meth:`state_names`): DOLFINx functions (``function.NAME``), NumPy arrays
    #: (``array.NAME``) and plain values (``json.NAME``); ``None`` values (a part the
    #: scene does not use) are skipped. Everything else is set-up data, rebuilt by
    #: the constructor.
    checkpoint_state: tuple[str, ...] = ("timings",)

    @classmethod
    def state_names(cls) -> list[str]:
        """The declared :attr:`checkpoint_state` of this class and its bases, base first."""
        names: list[str] = []
        for klass in reversed(cls.__mro__):
            for name in vars(klass).get("checkpoint_state", ()):
                if name not in names:
                    names.append(name)
        return names

    def checkpoint(self) -> dict[str, np.ndarray]:
        """Everything this rank needs to continue bit-identically, as named arrays.

        The declared state (:meth:`state_names`): every DOLFINx ``Function``
        (all entries, ghosts included, with its dofmap), every NumPy array and
        every plain value (numbers, strings and lists / tuples / dicts of them,
        stored as JSON); the particle cloud (positions, cells, every field
        including hidden ones), the mesh partition and NumPy's global random
        state. Objects (forms, matrices, solvers) are rebuilt by the
        constructor; anything they cache must be recomputable from the saved
        state (operators are re-assembled when ``None`` or when ``dt`` changes).

        Raises
        ------
        TypeError
            If a declared attribute is none of these (a programming error).
        """
        from pfem2x import compat  # noqa: PLC0415

        Function = compat.dolfinx.fem.Function
        out: dict[str, np.ndarray] = {}
        for name in self.state_names():
            v = getattr(self, name, None)
            if v is None:
                continue
            if isinstance(v, Function):
                out[f"function.{name}"] = v.x.array.copy()
                out[f"dofmap.{name}"] = compat.dofmap_array(v.function_space)
            elif isinstance(v, np.ndarray) and v.dtype != object:
                out[f"array.{name}"] = v.copy()
            else:
                text = _json_or_none(v)
                if text is None:
                    raise TypeError(f"{type(self).__name__}.{name}: not storable state")
                out[f"json.{name}"] = np.array(text)
        # the partition: input index of every local cell (owned, then ghosts)
        out["mesh.cells"] = compat.original_cell_index(self.domain.mesh)
        out["mesh.owned"] = np.array(self.domain.table.num_cells_owned)
        cloud = self.cloud()
        if cloud is not None:
            out.update(_cloud_arrays(cloud))
        # pfem2x seeds its own generators; the legacy global state is kept for user code
        kind, keys, pos, has_gauss, cached = np.random.get_state()  # noqa: NPY002
        out["rng.keys"] = np.asarray(keys)
        out["rng.meta"] = np.array(json.dumps([kind, int(pos), int(has_gauss), float(cached)]))
        return out

    def _missing_state(self, data: dict[str, np.ndarray]) -> str:
        """The first declared state (not ``None`` here) that ``data`` lacks, or ``""``."""
        for name in self.state_names():
            if getattr(self, name, None) is None:
                continue
            if not any(f"{kind}.{name}" in data for kind in ("function", "array", "json")):
                return name
        cloud = self.cloud()
        if cloud is not None and "cloud_meta" in data:
            stored = json.loads(str(data["cloud_meta"]))["shapes"]
            for name in cloud.field_names:
                if name not in stored:
                    return f"particle field {name}"
        return ""

    def restore_checkpoint(
        self,
        data: dict[str, np.ndarray],
        load_rank: Callable[[int], dict[str, np.ndarray]] | None = None,
    ) -> None:
        """Put back the state of :meth:`checkpoint` (collective; same scene and rank count).

        Only the declared state (:meth:`state_names`) is read; other entries
        (e.g. set-up arrays that earlier versions stored) are ignored. When
        every rank has the mesh partition of the checkpoint (always serially;
        under MPI when the partitioner is deterministic) all arrays are put
        back as they were: the run continues bit-identically. Otherwise (the
        graph partitioner of some DOLFINx versions is not reproducible)
        functions and particles are re-distributed by the partition-independent
        input cell index, using the other ranks' data from ``load_rank(r)``;
        the per-rank arrays are then kept as built, and the run continues
        within round-off.

        Raises
        ------
        ValueError
            If the data does not fit (another mesh or solver), on every rank.
        """
        from pfem2x import compat  # noqa: PLC0415

        Function = compat.dolfinx.fem.Function
        missing = self._missing_state(data)
        if self.comm.allreduce(int(bool(missing)), op=MPI.MAX):
            what = f"{missing!r}" if missing else "the state of another rank"
            raise ValueError(f"the checkpoint lacks {what} of this solver ({self.name})")
        cells = compat.original_cell_index(self.domain.mesh)
        same = int(np.array_equal(cells, data.get("mesh.cells")))
        same = bool(self.comm.allreduce(same, op=MPI.MIN))
        if not same and load_rank is None:
            raise ValueError("the mesh partition differs from the checkpoint's")
        others = None if same else [load_rank(r) for r in range(self.comm.size)]
        for name in self.state_names():
            old = getattr(self, name, None)
            if old is None:
                continue
            if isinstance(old, Function):
                v = data.get(f"function.{name}")
                if v is None:
                    raise ValueError(f"function {name} is not in the checkpoint")
                if same:
                    if old.x.array.shape != v.shape:
                        raise ValueError(f"function {name} does not fit this solver")
                    old.x.array[:] = v
                else:
                    _redistribute_function(old, name, others, cells, compat)
            elif f"array.{name}" in data:
                if not same:
                    continue  # per-rank arrays: kept as built
                v = data[f"array.{name}"]
                if isinstance(old, np.ndarray) and old.shape == v.shape and old.flags.writeable:
                    old[...] = v
                else:
                    setattr(self, name, v.copy())
            elif f"json.{name}" in data:
                setattr(self, name, _like(json.loads(str(data[f"json.{name}"])), old))
        cloud = self.cloud()
        if cloud is not None and "cloud.x" in data:
            if same:
                _restore_cloud(cloud, data)
            else:
                _restore_cloud(cloud, _gather_particles(others, cells, cloud.pmesh.n_owned))
        if "rng.keys" in data:
            kind, pos, has_gauss, cached = json.loads(str(data["rng.meta"]))
            np.random.set_state((kind, data["rng.keys"], pos, has_gauss, cached))  # noqa: NPY002


def _redistribute_function(
    u: Any, name: str, others: list[dict[str, np.ndarray]], cells: np.ndarray, compat: Any
) -> None:
    """Set ``u`` from all ranks' saved values, matched by (input cell, local dof)."""
    bs = int(u.function_space.dofmap.index_map_bs)
    keys, vals = [], []
    for d in others:
        n_owned = int(d["mesh.owned"])
        dm = d[f"dofmap.{name}"][:n_owned]
        keys.append(d["mesh.cells"][:n_owned])
        vals.append(d[f"function.{name}"].reshape(-1, bs)[dm])  # (cells, dofs, bs)
    gkeys = np.concatenate(keys)
    gvals = np.concatenate(vals)
    order = np.argsort(gkeys, kind="stable")
    pos = order[np.searchsorted(gkeys, cells, sorter=order)]
    if not np.array_equal(gkeys[pos], cells):
        raise ValueError(f"function {name}: the checkpoint's mesh has other cells")
    dm = compat.dofmap_array(u.function_space)[: len(cells)]
    u.x.array.reshape(-1, bs)[dm] = gvals[pos]
    u.x.scatter_forward()


def _gather_particles(
    others: list[dict[str, np.ndarray]], cells: np.ndarray, n_owned: int
) -> dict[str, np.ndarray]:
    """The saved particles of all ranks that lie in this rank's owned cells."""
    meta = json.loads(str(others[0]["cloud_meta"]))
    names = ["cloud.x", *[f"cloud.f.{k}" for k in meta["shapes"]]]
    owned = cells[:n_owned]
    order = np.argsort(owned)
    parts: dict[str, list[np.ndarray]] = {k: [] for k in [*names, "cloud.cells"]}
    for d in others:
        gc = d["mesh.cells"][d["cloud.cells"]]
        i = np.clip(np.searchsorted(owned, gc, sorter=order), 0, max(len(owned) - 1, 0))
        mine = (owned[order[i]] == gc) if len(owned) else np.zeros(len(gc), dtype=bool)
        for k in names:
            parts[k].append(d[k][mine])
        parts["cloud.cells"].append(order[i[mine]].astype(np.int32))
    out = {k: np.concatenate(v) for k, v in parts.items()}
    out["cloud_meta"] = np.array(json.dumps({"shapes": meta["shapes"], "sorted": False}))
    return out


def _json_or_none(v: Any) -> str | None:
    """``v`` as JSON if it is plain data (numbers, strings, None, containers), else None."""

    def plain(x: Any) -> bool:
        if x is None or isinstance(x, bool | int | float | str | np.integer | np.floating):
            return True
        if isinstance(x, list | tuple):
            return all(plain(y) for y in x)
        if isinstance(x, dict):
            return all(isinstance(k, str) and plain(y) for k, y in x.items())
        return False

    if not plain(v):
        return None
    return json.dumps(v, default=lambda o: o.item())


def _like(val: Any, old: Any) -> Any:
    """A JSON value back in the container types of ``old`` (tuples stay tuples)."""
    if isinstance(old, tuple) and isinstance(val, list):
        return tuple(_like(v, o) for v, o in zip(val, old, strict=False)) + tuple(val[len(old) :])
    if isinstance(old, dict) and isinstance(val, dict):
        return {k: _like(v, old.get(k)) for k, v in val.items()}
    return val


def _cloud_arrays(cloud: Any, into: dict[str, np.ndarray] | None = None) -> dict[str, np.ndarray]:
    """Positions, cells and every field (hidden ones too) of a particle cloud (copies;
    ``into``: an earlier result, whose arrays take them where they have room)."""
    old = into or {}
    prev = {"__x": old.get("cloud.x"), "__c": old.get("cloud.cells")}
    prev.update({k[len("cloud.f.") :]: v for k, v in old.items() if k.startswith("cloud.f.")})
    raw = cloud.extract(into={k: v for k, v in prev.items() if v is not None})
    out = {"cloud.x": raw.pop("__x"), "cloud.cells": raw.pop("__c")}
    shapes = {k: list(cloud.field_shape(k)) for k in raw}
    out.update({f"cloud.f.{k}": v for k, v in raw.items()})
    out["cloud_meta"] = np.array(json.dumps({"shapes": shapes, "sorted": cloud.is_sorted}))
    return out


def _restore_cloud(cloud: Any, data: dict[str, np.ndarray]) -> None:
    meta = json.loads(str(data["cloud_meta"]))
    for name, shape in meta["shapes"].items():
        if name not in cloud:
            cloud.add_field(name, tuple(shape))
    cloud.remove(np.ones(cloud.n, dtype=bool))
    values = {k: data[f"cloud.f.{k}"] for k in meta["shapes"]}
    cloud.append(data["cloud.x"], data["cloud.cells"], values)
    if meta["sorted"]:
        cloud.sort_by_cell()  # already in cell order: only rebuilds the offsets
    else:
        cloud.invalidate_order()
