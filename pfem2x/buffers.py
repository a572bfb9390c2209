"""Copies into storage kept from an earlier copy: no new arrays, no page faults.

A run keeps its last good state (:class:`pfem2x.output.LastGood`) after every step: a
copy of the fields and of the particle cloud, whose particle count changes from step to
step. Copied into new arrays, each step pays for the operating system's first touch of
their pages as well; copied into the arrays of the step before, only for the copy.
"""

from __future__ import annotations

import numpy as np

__all__ = ["copy_into"]


def copy_into(a: np.ndarray, old: np.ndarray) -> np.ndarray:
    """A copy of ``a`` in the storage of ``old`` where it has room for ``a``'s rows.

    Parameters
    ----------
    a
        The array to copy.
    old
        An earlier result of this function (its storage is the array it views), or
        any array. It is overwritten.

    Returns
    -------
    np.ndarray
        A view of the first ``len(a)`` rows of the storage: ``old``'s, or new storage
        with a quarter more rows than ``a`` (room for the next copy) when ``old``'s
        dtype, row shape or room do not fit.
    """
    store = old.base if isinstance(old.base, np.ndarray) else old
    if (
        store.dtype != a.dtype
        or store.shape[1:] != a.shape[1:]
        or len(store) < len(a)
        or not store.flags.c_contiguous
        or not store.flags.writeable
    ):
        store = np.empty((len(a) + len(a) // 4, *a.shape[1:]), dtype=a.dtype)
    out = store[: len(a)]
    np.copyto(out, a)
    return out
