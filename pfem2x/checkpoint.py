"""Restart checkpoints: find, write (atomically) and load.

A checkpoint folder holds ``meta.json`` (written last: it marks the folder
complete), ``history.json`` (the diagnostics so far) and one ``rank{r}.npz``
per MPI rank (the solver's :meth:`~pfem2x.physics.base.Solver.checkpoint`).
It is written into ``.checkpoint.tmp/`` and renamed to ``checkpoint/``; the
previous one survives as ``.checkpoint.old/`` until the rename is done.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import zipfile
import zlib
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from pfem2x import io as pio

if TYPE_CHECKING:
    from mpi4py import MPI

    from pfem2x.physics.base import Solver
    from pfem2x.scene import Scene

__all__ = [
    "CHECKPOINT",
    "CHECKPOINT_OLD",
    "CHECKPOINT_TMP",
    "digest",
    "find_checkpoint",
    "load_checkpoint",
    "write_checkpoint",
]

#: names of the checkpoint folders in the output folder
CHECKPOINT, CHECKPOINT_TMP, CHECKPOINT_OLD = "checkpoint", ".checkpoint.tmp", ".checkpoint.old"
#: the checkpoint format this code writes and reads
FORMAT = 1


def digest(text: str) -> str:
    """SHA-256 hex digest of a text (the scene hash stored in ``meta.json``)."""
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def find_checkpoint(out_dir: Path) -> tuple[Path, dict[str, Any]] | None:
    """The newest complete checkpoint of a run folder as ``(folder, meta)``, or ``None``.

    A checkpoint is complete when its ``meta.json`` (written last), its
    ``history.json`` and one ``rank{r}.npz`` per rank exist. ``checkpoint/``
    is tried first, then ``.checkpoint.old/`` (the previous one, kept while a
    new one is renamed into place); a ``.checkpoint.tmp/`` being written is
    never used.
    """
    for name in (CHECKPOINT, CHECKPOINT_OLD):
        d = Path(out_dir) / name
        try:
            meta = json.loads((d / "meta.json").read_text(encoding="utf-8"))
            size = int(meta["mpi_size"])
            if not (d / "history.json").is_file():
                continue
            if all((d / f"rank{r}.npz").is_file() for r in range(size)):
                return d, meta
        except (OSError, ValueError, KeyError, TypeError):
            continue
    return None


def check_meta(ck: Path, meta: dict[str, Any]) -> str:
    """An error text when ``meta`` lacks what :func:`load_checkpoint` needs, else ``""``."""
    fmt = meta.get("format")
    if fmt != FORMAT:
        return f"{ck}: checkpoint format {fmt!r} is not supported (this version reads {FORMAT})"
    need = ("step", "t", "dt", "mpi_size", "scene_hash", "source", "base_dir", "loop")
    missing = [k for k in need if k not in meta]
    if missing or not isinstance(meta.get("loop"), dict):
        return f"{ck}: meta.json lacks {', '.join(missing) or 'loop'}; not a pfem2x checkpoint"
    return ""


def _all_ok(comm: MPI.Comm, err: str) -> str:
    errs = comm.allgather(err)
    return next((e for e in errs if e), "")


def write_checkpoint(
    comm: MPI.Comm,
    out: Path,
    solver: Solver,
    scene: Scene,
    scene_text: str,
    loop: dict[str, Any],
    history: list[dict[str, float]],
    extra: dict[str, Any],
) -> str:
    """Write ``out/checkpoint/`` atomically (collective).

    Parameters
    ----------
    comm:
        The run's communicator.
    out:
        The run folder.
    solver:
        Its :meth:`checkpoint` arrays go to ``rank{r}.npz``.
    scene:
        Its source and base folder go to ``meta.json``.
    scene_text:
        The run's ``scene.toml`` text, hashed into ``meta.json`` (checked on resume).
    loop:
        The runner's loop state (``meta["loop"]``) at the step written.
    history:
        The diagnostics so far (``history.json``).
    extra:
        Further ``meta.json`` entries (operators, particle outputs, ...).

    Returns
    -------
    str
        An error text, or ``""`` when the checkpoint was written (same on all ranks).
    """
    from pfem2x import compat  # noqa: PLC0415

    tmp = out / CHECKPOINT_TMP
    data = solver.checkpoint()
    err = ""
    if comm.rank == 0:
        try:
            shutil.rmtree(tmp, ignore_errors=True)
            tmp.mkdir()
        except OSError as exc:
            err = f"{tmp}: {exc.strerror or exc}"
    err = comm.bcast(err, root=0)
    if err:
        return err
    try:
        with open(tmp / f"rank{comm.rank}.npz", "wb") as f:
            np.savez(f, **data)
    except OSError as exc:
        err = f"{tmp}: {exc.strerror or exc}"
    err = _all_ok(comm, err)
    if err:
        return err
    if comm.rank == 0:
        meta = {
            "format": FORMAT,
            "step": loop["step"],
            "t": loop["t"],
            "dt": loop["dt"],
            "mpi_size": comm.size,
            "scene_hash": digest(scene_text),
            "source": scene.source,
            "base_dir": str(scene.base_dir),
            "dolfinx_version": compat.dolfinx.__version__,
            "loop": loop,
            **extra,
        }
        err = _publish(out, meta, history)
    return comm.bcast(err, root=0)


def _publish(out: Path, meta: dict[str, Any], history: list[dict[str, float]]) -> str:
    """Complete ``.checkpoint.tmp/`` and rename it to ``checkpoint/`` (rank 0)."""
    tmp, final, old = out / CHECKPOINT_TMP, out / CHECKPOINT, out / CHECKPOINT_OLD
    try:
        pio.atomic_write_text(tmp / "history.json", json.dumps(history))
        pio.write_json(tmp / "meta.json", meta)  # last: marks the folder complete
        if final.exists():
            shutil.rmtree(old, ignore_errors=True)
            os.replace(final, old)
        os.replace(tmp, final)
        shutil.rmtree(old, ignore_errors=True)
    except OSError as exc:
        return f"{final}: {exc.strerror or exc}"
    return ""


class _Damaged(Exception):
    """A checkpoint file that cannot be read (its text names the file)."""


def load_checkpoint(comm: MPI.Comm, ck: Path, solver: Solver) -> tuple[list[dict[str, float]], str]:
    """Restore the solver from checkpoint folder ``ck`` (collective).

    Returns
    -------
    (history, error)
        The stored diagnostics history and an error text (``""`` when restored;
        the same on all ranks).
    """
    history, err = None, ""
    if comm.rank == 0:
        try:
            history = json.loads((ck / "history.json").read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            err = f"{ck / 'history.json'}: cannot read ({exc})"
    history, err = comm.bcast((history, err), root=0)
    if err:
        return [], err

    def load(r: int) -> dict[str, np.ndarray]:
        path = ck / f"rank{r}.npz"
        try:
            with np.load(path) as f:
                return {k: f[k] for k in f.files}
        except (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error) as exc:
            raise _Damaged(f"{path}: damaged checkpoint file, cannot read it ({exc})") from None

    try:
        solver.restore_checkpoint(load(comm.rank), load)
    except _Damaged as exc:
        err = str(exc)
    except (ValueError, OSError, KeyError) as exc:
        err = f"{ck}: {exc}"
    return history, _all_ok(comm, err)
