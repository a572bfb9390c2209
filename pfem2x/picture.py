"""The 2D PNG snapshot: a P1 field rasterised on the picture's pixels, a colour bar, the interface.

:func:`png_2d` draws one snapshot with numpy and Pillow: no plotting library is imported
(matplotlib's import and the layout of its artists cost more than the drawing itself:
docs/BENCHMARKS.md, "The 2D PNG drawn with Pillow").
What does not change between the snapshots of a mesh (:class:`Canvas`) is drawn once:
the pixels' barycentric weights, the frame, the axes' ticks and labels and the colour
bar's gradient. Each snapshot draws the field, the interface, the colour bar's ticks for
its range, its label and the title onto a copy of that.

The field is an image of the plot area's pixels: each pixel centre lies in one triangle
and takes the P1 interpolant there, the barycentric weights of every pixel computed
once per mesh (:func:`raster_weights`), coloured with viridis. Pixels that no triangle
covers (outside the domain) and values that are not finite stay blank (white). Lines
(the interface in red, an iso-line in white) are drawn with their width on a grid of
:data:`SUPER` × :data:`SUPER` sub-pixels per pixel, each pixel blended by the share of
its sub-pixels a line covers (anti-aliased).

The layout is matplotlib's of a figure at :data:`DPI` with the same places in inches:
the plot area in the domain's aspect ratio, longest side 6.5 inches, ticks and labels
in 10 pt text, the colour bar right of it.
"""

from __future__ import annotations

import functools
import math
from typing import Any

import numpy as np

__all__ = ["Canvas", "iso_segments", "nice_ticks", "png_2d", "raster_weights", "tick_labels"]

#: Pixels per inch of the saved PNG.
DPI = 110
#: Candidate (triangle, pixel) pairs per chunk of :func:`raster_weights`.
_CHUNK = 1 << 22
#: Sub-pixels per pixel side on which lines are drawn (anti-aliasing).
SUPER = 4
#: Points to pixels.
_PT = DPI / 72.0
#: The interface's colour and width (pixels), an iso-line's.
_INTERFACE = ((255, 48, 48), 1.2 * _PT)
_ISO_LINE = ((255, 255, 255), 1.5 * _PT)
#: viridis, 256 colours (8 bits per channel), as matplotlib's table.
_VIRIDIS_HEX = (
    "44015444025645045745055946075a46085c460a5d460b5e470d60470e61471063471164471365481467481668481769"
    "48186a481a6c481b6d481c6e481d6f481f70482071482173482374482475482576482677482878482979472a7a472c7a"
    "472d7b472e7c472f7d46307e46327e46337f463480453581453781453882443983443a83443b84433d84433e85423f85"
    "4240864241864142874144874045884046883f47883f48893e49893e4a893e4c8a3d4d8a3d4e8a3c4f8a3c508b3b518b"
    "3b528b3a538b3a548c39558c39568c38588c38598c375a8c375b8d365c8d365d8d355e8d355f8d34608d34618d33628d"
    "33638d32648e32658e31668e31678e31688e30698e306a8e2f6b8e2f6c8e2e6d8e2e6e8e2e6f8e2d708e2d718e2c718e"
    "2c728e2c738e2b748e2b758e2a768e2a778e2a788e29798e297a8e297b8e287c8e287d8e277e8e277f8e27808e26818e"
    "26828e26828e25838e25848e25858e24868e24878e23888e23898e238a8d228b8d228c8d228d8d218e8d218f8d21908d"
    "21918c20928c20928c20938c1f948c1f958b1f968b1f978b1f988b1f998a1f9a8a1e9b8a1e9c891e9d891f9e891f9f88"
    "1fa0881fa1881fa1871fa28720a38620a48621a58521a68522a78522a88423a98324aa8325ab8225ac8226ad8127ad81"
    "28ae8029af7f2ab07f2cb17e2db27d2eb37c2fb47c31b57b32b67a34b67935b77937b87838b9773aba763bbb753dbc74"
    "3fbc7340bd7242be7144bf7046c06f48c16e4ac16d4cc26c4ec36b50c46a52c56954c56856c66758c7655ac8645cc863"
    "5ec96260ca6063cb5f65cb5e67cc5c69cd5b6ccd5a6ece5870cf5773d05675d05477d1537ad1517cd2507fd34e81d34d"
    "84d44b86d54989d5488bd6468ed64590d74393d74195d84098d83e9bd93c9dd93ba0da39a2da37a5db36a8db34aadc32"
    "addc30b0dd2fb2dd2db5de2bb8de29bade28bddf26c0df25c2df23c5e021c8e020cae11fcde11dd0e11cd2e21bd5e21a"
    "d8e219dae319dde318dfe318e2e418e5e419e7e419eae51aece51befe51cf1e51df4e61ef6e620f8e621fbe723fde725"
)


@functools.cache
def _viridis() -> np.ndarray:
    """The ``(256, 3)`` uint8 colour table (decoded once)."""
    table = np.frombuffer(bytes.fromhex("".join(_VIRIDIS_HEX)), np.uint8).reshape(256, 3)
    table.flags.writeable = False
    return table


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


def nice_ticks(lo: float, hi: float, most: int) -> np.ndarray:
    """At most ``most`` (and at least 2, where the range allows) round values in ``[lo, hi]``.

    Multiples of the smallest step 1, 2, 2.5 or 5 × 10^k that keeps their number within
    ``most``; ``[lo]`` when the range is empty or not finite.
    """
    if not (math.isfinite(lo) and math.isfinite(hi)) or hi <= lo:
        return np.array([lo])
    most = max(int(most), 2)
    base = 10.0 ** math.floor(math.log10((hi - lo) / most))
    for step in (base * m for m in (1.0, 2.0, 2.5, 5.0, 10.0, 20.0)):
        k0, k1 = math.ceil(lo / step - 1e-9), math.floor(hi / step + 1e-9)
        if k1 - k0 + 1 <= most:
            return np.arange(k0, k1 + 1) * step
    return np.array([lo, hi])  # pragma: no cover (a step of 20 x base always fits)


def tick_labels(ticks: np.ndarray) -> list[str]:
    """Labels of :func:`nice_ticks`: the step's decimals (``0.25``, ``-1.5``, ``100``).

    Values of 10^5 and more in size, or steps below 10^-6, with the significant digits
    the step needs (``1.5e+05``).
    """
    t = np.asarray(ticks, dtype=float)
    if len(t) < 2:
        return [f"{v:.4g}" for v in t]
    step = abs(float(t[1] - t[0]))
    extra = round(step / 10.0 ** math.floor(math.log10(step) + 1e-9), 6) % 1 != 0  # 2.5
    digits = max(0, -math.floor(math.log10(step) + 1e-9)) + extra
    top = float(np.max(np.abs(t)))
    if digits <= 6 and top < 1e5:
        return [f"{round(v, digits) + 0.0:.{digits}f}" for v in t]
    size = math.floor(math.log10(top)) if top > 0 else 0
    sig = max(size - math.floor(math.log10(step) + 1e-9) + 1 + extra, 1)
    return [f"{v:.{sig}g}" for v in t]


def iso_segments(coords: np.ndarray, vals: np.ndarray, level: float) -> np.ndarray:
    """The iso-line ``vals = level`` of a P1 field as ``(m, 2, 2)`` segments, one per cut triangle.

    ``coords (n, nv, >= 2)``, ``vals (n, nv)``: the first three vertices are the
    triangle. A vertex at the level counts as above it.
    """
    x = np.asarray(coords)[:, :3, :2]
    v = np.asarray(vals, dtype=float)[:, :3]
    up = v >= level
    cut = np.isfinite(v).all(axis=1) & up.any(axis=1) & ~up.all(axis=1)
    x, v, up = x[cut], v[cut], up[cut]
    points = []
    for a, b in ((0, 1), (1, 2), (2, 0)):
        crossed = up[:, a] != up[:, b]
        with np.errstate(divide="ignore", invalid="ignore"):
            s = np.where(crossed, (level - v[:, a]) / (v[:, b] - v[:, a]), 0.0)
        points.append((crossed, x[:, a] + s[:, None] * (x[:, b] - x[:, a])))
    crossed = np.stack([c for c, _ in points], 1)  # two of the three edges of each triangle
    xy = np.stack([p for _, p in points], 1)
    return xy[crossed].reshape(-1, 2, 2)


def _coverage(segments: np.ndarray, shape: tuple[int, int], width: float) -> np.ndarray | None:
    """The share ``(rows, cols)`` of each pixel's sub-pixels within ``width / 2`` of a segment.

    ``segments (m, 2, 2)`` in pixel coordinates of the area (x right, y down, pixel
    ``(i, j)`` spans ``[i, i + 1] x [j, j + 1]``); ``None`` when nothing is drawn.
    """
    seg = np.asarray(segments, dtype=float).reshape(-1, 2, 2) * SUPER
    seg = seg[np.isfinite(seg).all(axis=(1, 2))]
    if len(seg) == 0:
        return None
    rows, cols = shape[0] * SUPER, shape[1] * SUPER
    r = 0.5 * width * SUPER
    R = int(math.ceil(r)) + 1
    d = seg[:, 1] - seg[:, 0]
    n = np.ceil(np.hypot(d[:, 0], d[:, 1])).astype(np.int64) + 1  # a sample every sub-pixel
    which = np.repeat(np.arange(len(seg)), n)
    k = np.arange(len(which)) - np.repeat(np.cumsum(n) - n, n)
    s = k / np.repeat(np.maximum(n - 1, 1), n)
    p = seg[which, 0] + s[:, None] * d[which]
    p = p[(p[:, 0] > -R) & (p[:, 0] < cols + R) & (p[:, 1] > -R) & (p[:, 1] < rows + R)]
    if len(p) == 0:
        return None
    i, j = np.floor(p[:, 0]).astype(np.int64), np.floor(p[:, 1]).astype(np.int64)
    fx, fy = p[:, 0] - i - 0.5, p[:, 1] - j - 0.5  # the sample from its sub-pixel's centre
    mask = np.zeros((rows + 4 * R, cols + 4 * R), dtype=np.uint8)  # a margin of 2 R
    for dj in range(-R, R + 1):  # the sub-pixels whose centres lie within r of a sample
        for di in range(-R, R + 1):
            near = (di - fx) ** 2 + (dj - fy) ** 2 <= r * r
            mask[j[near] + dj + 2 * R, i[near] + di + 2 * R] = 1
    inner = mask[2 * R : 2 * R + rows, 2 * R : 2 * R + cols]
    # the pixel rows the lines reach, their sub-pixels summed one sub-row and sub-column
    # at a time (cheaper than numpy's sum over two short axes)
    first = max(int(j.min()) - R, 0) // SUPER
    last = min((int(j.max()) + R) // SUPER + 1, shape[0])
    part = inner[first * SUPER : last * SUPER].reshape(last - first, SUPER, shape[1], SUPER)
    total = np.zeros((last - first, shape[1]), dtype=np.uint8)
    for a in range(SUPER):
        for b in range(SUPER):
            total += part[:, a, :, b]
    cover = np.zeros(shape)
    cover[first:last] = total / float(SUPER * SUPER)
    return cover


def _font(px: int) -> Any:
    """Pillow's own font at ``px`` pixels (its bitmap font where FreeType is missing)."""
    from PIL import ImageFont  # noqa: PLC0415

    try:
        return ImageFont.load_default(size=px)
    except (TypeError, ImportError, OSError):  # Pillow < 10.1, or no FreeType
        return ImageFont.load_default()


def _text(draw: Any, font: Any, s: str, x: float, y: float, ha: str, va: str) -> float:
    """Draw ``s`` black with its ink's box at ``x`` (``ha``: l, c, r) and ``y`` (``va``: t, m, b).

    Returns the box's width.
    """
    left, top, right, bottom = font.getbbox(s)
    w, h = right - left, bottom - top
    x0 = x - {"l": 0.0, "c": 0.5 * w, "r": w}[ha]
    y0 = y - {"t": 0.0, "m": 0.5 * h, "b": h}[va]
    draw.text((round(x0 - left), round(y0 - top)), s, font=font, fill=(0, 0, 0))
    return float(w)


def _text_up(image: Any, font: Any, s: str, x: float, y: float) -> None:
    """Draw ``s`` black, turned a quarter left, its box's left edge at ``x``, centred on ``y``."""
    from PIL import Image, ImageDraw  # noqa: PLC0415

    left, top, right, bottom = font.getbbox(s)
    tile = Image.new("L", (right - left + 2, bottom - top + 2), 0)
    ImageDraw.Draw(tile).text((1 - left, 1 - top), s, font=font, fill=255)
    tile = tile.rotate(90, expand=True)
    image.paste((0, 0, 0), (round(x), round(y - 0.5 * tile.height)), tile)


class Canvas:
    """The 2D snapshot picture of one mesh: the field, its colour bar, the interface.

    Built once per mesh (the pixels' weights and what every snapshot shares: the frame,
    the axes' ticks and labels, the colour bar's gradient, in :attr:`background`); each
    :meth:`save` draws a snapshot's field, lines and texts on a copy of it. Places as in
    inches of a matplotlib figure at :data:`DPI`: the plot area 0.75 in from the left of
    its column and 0.6 in above the bottom, the colour bar 0.2 in right of it, 0.15 in
    wide over the middle 80 % of its height, 1.1 in for its labels; the picture at least
    5 in wide for the title.

    Parameters
    ----------
    coords
        ``(n, nv, 2)`` vertex coordinates of each cell (the first three: the triangle).
    """

    def __init__(self, coords: np.ndarray) -> None:
        self.coords = coords.copy()
        pts = coords.reshape(-1, coords.shape[2])
        self.lo, self.hi = pts[:, :2].min(axis=0), pts[:, :2].max(axis=0)
        span = np.maximum(self.hi - self.lo, 1e-30)
        aspect = float(np.clip(span[1] / span[0], 0.2, 5.0))
        w, h = (6.5, 6.5 * aspect) if aspect <= 1 else (6.5 / aspect, 6.5)
        W, H = round(w * DPI), round(h * DPI)  # the plot's region, pixels
        column = W + round(2.2 * DPI)
        self.size = (max(column, round(5.0 * DPI)), H + round(0.95 * DPI))  # (width, height)
        x0 = (self.size[0] - column) // 2 + round(0.75 * DPI)
        y0 = self.size[1] - round(0.6 * DPI) - H
        # the raster: the pixels of the equal-aspect plot box, centred in its region
        scale = min(W / span[0], H / span[1])
        self.shape = (max(int(round(span[1] * scale)), 1), max(int(round(span[0] * scale)), 1))
        rows, cols = self.shape
        self.box = (x0 + (W - cols) // 2, y0 + (H - rows) // 2)  # (left, top)
        self.bar = (
            x0 + W + round(0.2 * DPI),
            y0 + round(0.1 * H),
            round(0.15 * DPI),
            round(0.8 * H),
        )
        self.pixels, self.cells, self.weights = raster_weights(coords, self.lo, self.hi, self.shape)
        self.font = _font(round(10 * _PT))
        self.tick, self.pad = round(3.5 * _PT), round(3.5 * _PT)
        #: the colour bar's label of the last snapshot
        self.bar_label = ""
        self.background = self._background()

    def _background(self) -> np.ndarray:
        """What every snapshot shares, ``(height, width, 3)`` uint8."""
        from PIL import Image, ImageDraw  # noqa: PLC0415

        img = np.full((self.size[1], self.size[0], 3), 255, np.uint8)
        bx, by, bw, bh = self.bar
        frac = (bh - 1 - np.arange(bh) + 0.5) / bh  # the gradient, top row the largest
        img[by : by + bh, bx : bx + bw] = _viridis()[np.minimum(frac * 256, 255).astype(int)][
            :, None
        ]
        image = Image.fromarray(img)
        draw = ImageDraw.Draw(image)
        (left, top), (rows, cols) = self.box, self.shape
        for x, y, w, h in ((left, top, cols, rows), self.bar):  # the frames
            draw.rectangle((x - 1, y - 1, x + w, y + h), outline=(0, 0, 0))
        font, tick, pad = self.font, self.tick, self.pad
        xt = nice_ticks(float(self.lo[0]), float(self.hi[0]), max(2, cols // 55))
        bottom = top + rows + 1 + tick + pad
        height = 0.0
        for t, s in zip(xt, tick_labels(xt), strict=True):
            x = left + round((t - self.lo[0]) / (self.hi[0] - self.lo[0]) * cols)
            x = min(x, left + cols)
            draw.line((x, top + rows + 1, x, top + rows + tick), fill=(0, 0, 0))
            _text(draw, font, s, x, bottom, "c", "t")
            box = font.getbbox(s)
            height = max(height, box[3] - box[1])
        _text(draw, font, "x", left + 0.5 * cols, bottom + height + 2 * pad, "c", "t")
        yt = nice_ticks(float(self.lo[1]), float(self.hi[1]), max(2, rows // 55))
        width = 0.0
        for t, s in zip(yt, tick_labels(yt), strict=True):
            y = top + rows - round((t - self.lo[1]) / (self.hi[1] - self.lo[1]) * rows)
            y = max(y, top - 1)
            draw.line((left - 1 - tick, y, left - 2, y), fill=(0, 0, 0))
            width = max(width, _text(draw, font, s, left - 1 - tick - pad, y, "r", "m"))
        b = font.getbbox("y")
        _text_up(
            image, font, "y", left - 1 - tick - 2 * pad - width - (b[3] - b[1]), top + rows / 2
        )
        return np.asarray(image).copy()

    def raster(self, vals: np.ndarray) -> np.ndarray:
        """The P1 field of per-cell vertex values ``vals (n, nv)`` at the pixel centres.

        ``(rows, columns)``, row 0 at the bottom; NaN where no triangle covers a pixel.
        """
        img = np.full(self.shape[0] * self.shape[1], np.nan)
        v = np.asarray(vals, dtype=float)[self.cells, :3]
        img[self.pixels] = np.einsum("ij,ij->i", self.weights, v)
        return img.reshape(self.shape)

    def _to_pixels(self, segments: np.ndarray) -> np.ndarray:
        """``(m, 2, 2)`` data coordinates in the plot box's pixels (y down)."""
        seg = np.asarray(segments, dtype=float).reshape(-1, 2, 2)
        rows, cols = self.shape
        span = np.maximum(self.hi - self.lo, 1e-30)
        px = (seg[..., 0] - self.lo[0]) / span[0] * cols
        py = (self.hi[1] - seg[..., 1]) / span[1] * rows
        return np.stack([px, py], axis=-1)

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
        from PIL import Image, ImageDraw  # noqa: PLC0415

        v = np.asarray(vals, dtype=float)
        fin = v[np.isfinite(v)]  # non-finite values stay blank pixels, out of the range
        lo, hi = (float(fin.min()), float(fin.max())) if fin.size else (0.0, 0.0)
        lo, hi = (lo, hi) if clim is None else (float(clim[0]), float(clim[1]))
        field = self.raster(v)[::-1]  # top row first
        ok = np.isfinite(field)
        scaled = (field[ok] - lo) / (hi - lo) if hi > lo else np.zeros(int(ok.sum()))
        rgb = np.full((*self.shape, 3), 255.0)
        rgb[ok] = _viridis()[np.clip(np.floor(scaled * 256), 0, 255).astype(int)]
        lines = [(segments, _INTERFACE)]
        if contour is not None:
            lines.append((iso_segments(self.coords, v, contour), _ISO_LINE))
        for seg, (colour, width) in lines:
            if seg is None or len(seg) == 0:
                continue
            a = _coverage(self._to_pixels(seg), self.shape, width)
            if a is not None:
                rgb += a[..., None] * (np.asarray(colour, dtype=float) - rgb)
        img = self.background.copy()
        (left, top), (rows, cols) = self.box, self.shape
        img[top : top + rows, left : left + cols] = np.round(rgb).astype(np.uint8)
        image = Image.fromarray(img)
        draw = ImageDraw.Draw(image)
        bx, by, bw, bh = self.bar
        ticks = nice_ticks(lo, hi, max(2, bh // 90))
        width = 0.0
        for t, s in zip(ticks, tick_labels(ticks), strict=True):
            y = by + bh - (round((t - lo) / (hi - lo) * bh) if hi > lo else 0)
            y = max(y, by - 1)
            draw.line((bx + bw + 1, y, bx + bw + self.tick, y), fill=(0, 0, 0))
            width = max(
                width, _text(draw, self.font, s, bx + bw + 1 + self.tick + self.pad, y, "l", "m")
            )
        self.bar_label = f"{label or 'value'}   [{lo:.4g}, {hi:.4g}]"
        _text_up(
            image,
            self.font,
            self.bar_label,
            bx + bw + 1 + self.tick + 2 * self.pad + width,
            by + bh / 2,
        )
        _text(draw, self.font, title, left + 0.5 * cols, top - 1 - round(6 * _PT), "c", "b")
        image.save(path, format="PNG")


#: The last 2D picture (rank 0), kept for the next snapshot of the same mesh.
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
        The colour range ``(lo, hi)``, or ``None``: the finite values' range.
    contour
        A value whose iso-line is drawn in white, or ``None``.
    segments
        ``(m, 2, 2)`` interface segments drawn in red, or ``None``.

    The picture of the last call is reused when the mesh is the same (:class:`Canvas`).
    """
    same = bool(_CANVAS) and _CANVAS[0].coords.shape == coords.shape
    if not (same and np.array_equal(_CANVAS[0].coords, coords)):
        _CANVAS[:] = [Canvas(coords)]
    _CANVAS[0].save(path, vals, title, clim, contour, label, segments)
