"""The 2D PNG snapshot: a P1 field rasterised on the figure's pixels, a colour bar, the interface.

:func:`png_2d` draws one snapshot with matplotlib on its own Agg canvas (the user's
pyplot backend is left as it is). The figure of a mesh (:class:`Canvas`) is built once
and kept for the next snapshot of the same mesh; each snapshot only sets the values,
the range, the interface and the texts.

The field is an image of the plot area's pixels: each pixel centre lies in one triangle
and takes the P1 interpolant there, the barycentric weights of every pixel computed
once per mesh (:func:`raster_weights`). That is what a P1 field is at each pixel (a
Gouraud-shaded triangle mesh interpolates the colours of the vertices instead, and
Agg's Gouraud fill of a mesh of many triangles was most of a snapshot's drawing).
Pixels that no triangle covers (outside the domain) stay blank.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["Canvas", "png_2d", "raster_weights"]

#: Pixels per inch of the saved PNG.
DPI = 110
#: Candidate (triangle, pixel) pairs per chunk of :func:`raster_weights`.
_CHUNK = 1 << 22


def raster_weights(
    coords: np.ndarray, lo: np.ndarray, hi: np.ndarray, shape: tuple[int, int]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The triangle and barycentric weights at each covered pixel centre of a raster.

    Parameters
    ----------
    coords
        ``(n, nv, >= 2)`` vertex coordinates of each cell; its first three vertices are
        the triangle.
    lo, hi
        The raster's lower-left and upper-right corners (data coordinates).
    shape
        ``(rows, columns)`` of the raster; row 0 is at ``lo[1]``.

    Returns
    -------
    pixels, cells, weights
        The flat indices ``row * columns + column`` of the covered pixels (each once),
        the cell covering each and its barycentric weights ``(m, 3)`` there. A pixel
        centre on a shared edge goes to one of its cells.
    """
    rows, cols = shape
    size = np.array([(hi[0] - lo[0]) / cols, (hi[1] - lo[1]) / rows])
    # vertices in pixel-index space: pixel (i, j) has its centre at (i, j)
    P = (np.asarray(coords)[:, :3, :2] - np.asarray(lo)[:2]) / size - 0.5
    i0 = np.clip(np.ceil(P[:, :, 0].min(axis=1)), 0, cols).astype(np.int64)
    i1 = np.clip(np.floor(P[:, :, 0].max(axis=1)), -1, cols - 1).astype(np.int64)
    j0 = np.clip(np.ceil(P[:, :, 1].min(axis=1)), 0, rows).astype(np.int64)
    j1 = np.clip(np.floor(P[:, :, 1].max(axis=1)), -1, rows - 1).astype(np.int64)
    ni = np.maximum(i1 - i0 + 1, 0)
    count = ni * np.maximum(j1 - j0 + 1, 0)
    e1 = P[:, 1] - P[:, 0]
    e2 = P[:, 2] - P[:, 0]
    det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    ends = np.cumsum(count)
    pix, cells, weights = [np.zeros(0, np.int64)], [np.zeros(0, np.int64)], [np.zeros((0, 3))]
    first = 0
    while first < len(count):  # chunks of cells with at most _CHUNK candidates (and one)
        base = ends[first - 1] if first else 0
        last = max(int(np.searchsorted(ends, base + _CHUNK, side="right")), first + 1)
        t = np.repeat(np.arange(first, last), count[first:last])
        k = np.arange(len(t)) - np.repeat(
            ends[first:last] - count[first:last] - base, count[first:last]
        )
        ii = i0[t] + k % np.maximum(ni[t], 1)
        jj = j0[t] + k // np.maximum(ni[t], 1)
        rx = ii - P[t, 0, 0]
        ry = jj - P[t, 0, 1]
        with np.errstate(divide="ignore", invalid="ignore"):
            l1 = (rx * e2[t, 1] - ry * e2[t, 0]) / det[t]
            l2 = (e1[t, 0] * ry - e1[t, 1] * rx) / det[t]
        l0 = 1.0 - l1 - l2
        eps = -1e-9
        inside = (det[t] != 0.0) & (l0 >= eps) & (l1 >= eps) & (l2 >= eps)
        pix.append(jj[inside] * cols + ii[inside])
        cells.append(t[inside])
        weights.append(np.stack([l0, l1, l2], 1)[inside])
        first = last
    p, once = np.unique(np.concatenate(pix), return_index=True)
    return p, np.concatenate(cells)[once], np.concatenate(weights)[once]


class Canvas:
    """A 2D snapshot figure of one mesh: the field, its colour bar and the interface.

    Snapshots of a run share the mesh, so the figure is built once (the pixels' weights,
    axes, ticks and colour bar) and each snapshot only sets the values, the range, the
    interface and the texts before it is saved. The axes sit at fixed places in inches
    (no layout engine measuring every tick label at each save): the plot area in the
    domain's aspect ratio, longest side 6.5 inches, with room for the tick labels, the
    title and the colour bar's labels; the figure at least 5 inches wide for the title.

    Parameters
    ----------
    coords
        ``(n, nv, 2)`` vertex coordinates of each cell (the first three: the triangle).
    """

    def __init__(self, coords: np.ndarray) -> None:
        from matplotlib.backends.backend_agg import FigureCanvasAgg  # noqa: PLC0415
        from matplotlib.figure import Figure  # noqa: PLC0415

        self.coords = coords.copy()
        pts = coords.reshape(-1, coords.shape[2])
        lo, hi = pts[:, :2].min(axis=0), pts[:, :2].max(axis=0)
        span = np.maximum(hi - lo, 1e-30)
        aspect = float(np.clip(span[1] / span[0], 0.2, 5.0))
        w, h = (6.5, 6.5 * aspect) if aspect <= 1 else (6.5 / aspect, 6.5)
        # inches: 0.75 left of the plot, 0.6 below, 0.2 to the bar, the bar 0.15, 1.1 for
        # its labels; the plot's edges on whole pixels (the raster's pixels are the PNG's)
        w, h = _whole(w), _whole(h)
        width = w + 2.2
        fw, fh = _whole(max(width, 5.0)), _whole(h + 0.95)
        x0 = _whole(0.5 * (fw - width) + 0.75)
        self.fig = Figure(figsize=(fw, fh))
        FigureCanvasAgg(self.fig)
        ax = self.fig.add_axes((x0 / fw, 0.6 / fh, w / fw, h / fh))
        cax = self.fig.add_axes(
            ((x0 + w + 0.2) / fw, (0.6 + 0.1 * h) / fh, 0.15 / fw, 0.8 * h / fh)
        )
        # the raster: the pixels of the equal-aspect plot box at DPI
        scale = min(w / span[0], h / span[1]) * DPI
        self.shape = (max(int(round(span[1] * scale)), 1), max(int(round(span[0] * scale)), 1))
        self.pixels, self.cells, self.weights = raster_weights(coords, lo, hi, self.shape)
        self.field = ax.imshow(
            np.ma.masked_all(self.shape),
            cmap="viridis",
            origin="lower",
            extent=(lo[0], hi[0], lo[1], hi[1]),
            interpolation="nearest",
        )
        ax.grid(False)
        # the interface: one line through every segment, NaN between them (one path to
        # draw instead of an object per segment)
        (self.lines,) = ax.plot([], [], color="#ff3030", linewidth=1.2, solid_capstyle="butt")
        self.bar = self.fig.colorbar(self.field, cax=cax)
        ax.set_aspect("equal")
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
        ax.set_xlabel("x")
        ax.set_ylabel("y")
        self.ax = ax

    def raster(self, vals: np.ndarray) -> np.ma.MaskedArray:
        """The P1 field of per-cell vertex values ``vals (n, nv)`` at the pixel centres."""
        img = np.full(self.shape[0] * self.shape[1], np.nan)
        v = np.asarray(vals)[self.cells, :3]
        img[self.pixels] = np.einsum("ij,ij->i", self.weights, v)
        return np.ma.masked_invalid(img.reshape(self.shape))

    def save(
        self,
        path: Any,
        vals: np.ndarray,
        title: str,
        clim: Any,
        contour: float | None,
        label: str,
        segments: np.ndarray | None,
    ) -> None:
        """Draw ``vals`` (per cell and vertex, as the coordinates) and save to ``path``."""
        v = np.asarray(vals)
        fin = v[np.isfinite(v)]  # non-finite values stay blank pixels, out of the range
        lo, hi = (float(fin.min()), float(fin.max())) if fin.size else (0.0, 0.0)
        lo, hi = (lo, hi) if clim is None else clim
        self.field.set_data(self.raster(v))
        self.field.set_clim(lo, hi)
        self.lines.set_data(*_polyline(segments).T)
        self.bar.set_label(f"{label or 'value'}   [{lo:.4g}, {hi:.4g}]")
        self.ax.set_title(title, fontsize=10)
        iso = None
        if contour is not None:  # on a triangulation of its own: tricontour keeps state in it
            pts = self.coords.reshape(-1, self.coords.shape[2])
            tris = np.arange(len(pts)).reshape(len(self.coords), -1)[:, :3]
            iso = self.ax.tricontour(
                pts[:, 0], pts[:, 1], tris, v.ravel(), levels=[contour], colors="w"
            )
        try:
            self.fig.savefig(path, dpi=DPI)
        finally:
            if iso is not None:
                iso.remove()


def _whole(inches: float) -> float:
    """``inches`` rounded to whole pixels of the saved PNG (:data:`DPI`)."""
    return round(inches * DPI) / DPI


def _polyline(segments: np.ndarray | None) -> np.ndarray:
    """``(m, 2, 2)`` segments as one ``(3m, 2)`` line with a NaN point after each segment."""
    if segments is None or len(segments) == 0:
        return np.zeros((0, 2))
    seg = np.asarray(segments, dtype=float).reshape(-1, 2, 2)
    return np.concatenate([seg, np.full((len(seg), 1, 2), np.nan)], axis=1).reshape(-1, 2)


#: The last 2D figure (rank 0), kept for the next snapshot of the same mesh.
_CANVAS: list[Canvas] = []


def png_2d(
    path: Any,
    coords: np.ndarray,
    vals: np.ndarray,
    title: str,
    clim: Any,
    contour: float | None,
    label: str = "",
    segments: np.ndarray | None = None,
) -> None:
    """A filled 2D plot: the domain's aspect ratio, a colour bar, the interface on top.

    Parameters
    ----------
    path
        The PNG file.
    coords, vals
        ``(n, nv, 2)`` vertex coordinates and ``(n, nv)`` values of each cell.
    title, label
        The title, and the colour bar's label (with the range).
    clim
        The colour range ``(lo, hi)``, or ``None``: the values' range.
    contour
        A value whose iso-line is drawn in white, or ``None``.
    segments
        ``(m, 2, 2)`` interface segments drawn in red, or ``None``.

    The figure of the last call is reused when the mesh is the same (:class:`Canvas`).
    """
    same = bool(_CANVAS) and _CANVAS[0].coords.shape == coords.shape
    if not (same and np.array_equal(_CANVAS[0].coords, coords)):
        _CANVAS[:] = [Canvas(coords)]
    _CANVAS[0].save(path, vals, title, clim, contour, label, segments)
