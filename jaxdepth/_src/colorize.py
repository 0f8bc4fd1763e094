"""Colour images of depth maps and normals for viewing (NumPy + OpenCV, host side).

Outputs are (H, W, 3) uint8 **RGB**.  No matplotlib: colour maps come from OpenCV's
``applyColorMap`` look-up tables (256 entries).  Not jit-able (display helpers).
"""

from __future__ import annotations

import cv2
import numpy as np

CMAPS = {
    "turbo": cv2.COLORMAP_TURBO,
    "jet": cv2.COLORMAP_JET,
    "viridis": cv2.COLORMAP_VIRIDIS,
    "inferno": cv2.COLORMAP_INFERNO,
    "magma": cv2.COLORMAP_MAGMA,
    "plasma": cv2.COLORMAP_PLASMA,
    "gray": None,
}


def colormap_lut(cmap: str = "turbo") -> np.ndarray:
    """(256, 3) uint8 RGB look-up table of ``cmap`` (index 0 = low end)."""
    if cmap not in CMAPS:
        raise ValueError(f"cmap: expected one of {sorted(CMAPS)}, got {cmap!r}")
    ramp = np.arange(256, dtype=np.uint8)[:, None]
    if CMAPS[cmap] is None:
        return np.repeat(ramp, 3, axis=1)
    bgr = cv2.applyColorMap(ramp, CMAPS[cmap])[:, 0, :]
    return np.ascontiguousarray(bgr[:, ::-1])


def colorize_depth(depth, *, vmin: float | None = None, vmax: float | None = None,
                   cmap: str = "turbo", invert: bool = False) -> np.ndarray:
    """Colour image of a depth map; empty pixels are black.

    Args:
      depth: (H, W) depth (NumPy or JAX array), metres; ``<= 0`` or non-finite = empty.
      vmin, vmax: depth range mapped to the ends of the colour map; default the
        minimum / maximum valid depth.  Values outside are clipped to the ends.
      cmap: one of ``"turbo"`` (default), ``"jet"``, ``"viridis"``, ``"inferno"``,
        ``"magma"``, ``"plasma"``, ``"gray"``.
      invert: map ``vmin`` to the high end instead (e.g. near = red with turbo).

    Returns:
      (H, W, 3) uint8 RGB.  A valid depth ``d`` gets LUT entry
      ``round(255 * (d - vmin) / (vmax - vmin))`` (``255 -`` that when ``invert``);
      every empty pixel is (0, 0, 0).
    """
    d = np.asarray(depth, dtype=np.float32)
    if d.ndim != 2:
        raise ValueError(f"depth: expected shape (H, W), got {d.shape}")
    lut = colormap_lut(cmap)
    valid = np.isfinite(d) & (d > 0)
    out = np.zeros(d.shape + (3,), np.uint8)
    if not valid.any():
        return out
    lo = float(d[valid].min()) if vmin is None else float(vmin)
    hi = float(d[valid].max()) if vmax is None else float(vmax)
    if not hi >= lo:
        raise ValueError(f"vmax: expected >= vmin ({lo}), got {hi}")
    span = hi - lo if hi > lo else 1.0
    t = np.clip((d[valid].astype(np.float64) - lo) / span, 0.0, 1.0)
    idx = np.rint(t * 255.0).astype(np.int64)
    if invert:
        idx = 255 - idx
    out[valid] = lut[idx]
    return out


def colorize_normals(normals) -> np.ndarray:
    """Colour image of a unit-normal field: RGB = (n + 1) / 2 * 255.

    Args:
      normals: (3, H, W) float (NumPy or JAX array), components (x, y, z) in [-1, 1]
        (clipped).

    Returns:
      (H, W, 3) uint8 RGB, ``round((n + 1) / 2 * 255)`` per channel; pixels whose
      normal is all zeros (no normal) or not finite are black.
    """
    n = np.asarray(normals, dtype=np.float32)
    if n.ndim != 3 or n.shape[0] != 3:
        raise ValueError(f"normals: expected shape (3, H, W), got {n.shape}")
    n = np.moveaxis(n, 0, -1)
    empty = ~np.all(np.isfinite(n), axis=-1) | np.all(n == 0, axis=-1)
    rgb = np.rint((np.clip(np.nan_to_num(n), -1.0, 1.0) + 1.0) * 0.5 * 255.0).astype(np.uint8)
    rgb[empty] = 0
    return rgb


def _rgb_canvas(image, shape, name: str) -> np.ndarray:
    img = np.asarray(image)
    if img.dtype != np.uint8:
        raise ValueError(f"{name}: field 'image' expected dtype uint8, got {img.dtype}")
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=-1)
    if img.ndim != 3 or img.shape[-1] != 3:
        raise ValueError(f"{name}: field 'image' expected shape (H, W) or (H, W, 3), got {img.shape}")
    if img.shape[:2] != tuple(shape):
        raise ValueError(f"{name}: field 'image' expected height, width {tuple(shape)}, got {img.shape[:2]}")
    return img.copy()


def _check_radius(radius, name: str) -> int:
    if isinstance(radius, bool) or int(radius) != radius or radius < 0:
        raise ValueError(f"{name}: field 'dot_radius_px' expected a non-negative integer, got {radius!r}")
    return int(radius)


def overlay_depth(image, depth, *, dot_radius_px: int = 1, vmin: float | None = None,
                  vmax: float | None = None, cmap: str = "turbo", invert: bool = False) -> np.ndarray:
    """Sparse depth painted over a camera image as coloured dots (nearest point on top).

    Args:
      image: (H, W, 3) uint8 RGB or (H, W) uint8 grey camera image.
      depth: (H, W) depth, metres; ``<= 0`` or non-finite = no point.
      dot_radius_px: each point becomes a (2r+1) x (2r+1) square; where squares
        overlap, the nearest depth wins (a min filter, as a z-buffer would).
      vmin, vmax, cmap, invert: as :func:`colorize_depth`; the default range is
        the minimum / maximum of the valid input depths (before the dots grow).

    Returns:
      (H, W, 3) uint8 RGB: ``image`` where no dot covers the pixel, else the colour
      :func:`colorize_depth` gives the smallest depth within ``dot_radius_px``
      (Chebyshev distance) of the pixel.
    """
    d = np.asarray(depth, dtype=np.float32)
    if d.ndim != 2:
        raise ValueError(f"overlay_depth: field 'depth' expected shape (H, W), got {d.shape}")
    r = _check_radius(dot_radius_px, "overlay_depth")
    out = _rgb_canvas(image, d.shape, "overlay_depth")
    valid = np.isfinite(d) & (d > 0)
    if not valid.any():
        return out
    lo = float(d[valid].min()) if vmin is None else float(vmin)
    hi = float(d[valid].max()) if vmax is None else float(vmax)
    z = np.where(valid, d, np.inf).astype(np.float32)
    if r > 0:
        z = cv2.erode(z, np.ones((2 * r + 1, 2 * r + 1), np.uint8), borderType=cv2.BORDER_CONSTANT,
                      borderValue=float(np.inf))
    covered = np.isfinite(z)
    colours = colorize_depth(np.where(covered, z, 0.0), vmin=lo, vmax=hi, cmap=cmap, invert=invert)
    out[covered] = colours[covered]
    return out


def overlay_mask(image, mask, *, color=(255, 0, 0), dot_radius_px: int = 1) -> np.ndarray:
    """Pixels of a mask painted over a camera image as squares of one colour.

    Args:
      image: (H, W, 3) uint8 RGB or (H, W) uint8 grey.
      mask: (H, W) bool (e.g. LiDAR pixels removed as outliers).
      color: RGB triple of integers in [0, 255] (default red).
      dot_radius_px: each True pixel becomes a (2r+1) x (2r+1) square.

    Returns:
      (H, W, 3) uint8 RGB: ``color`` within Chebyshev distance ``dot_radius_px``
      of a True pixel, ``image`` elsewhere.
    """
    m = np.asarray(mask)
    if m.ndim != 2 or m.dtype != bool:
        raise ValueError(f"overlay_mask: field 'mask' expected a (H, W) bool array, got {m.dtype} {m.shape}")
    r = _check_radius(dot_radius_px, "overlay_mask")
    rgb = np.asarray(color)
    if rgb.shape != (3,) or not np.all((rgb >= 0) & (rgb <= 255)) or not np.all(rgb == np.round(rgb)):
        raise ValueError(f"overlay_mask: field 'color' expected 3 integers in [0, 255], got {color!r}")
    out = _rgb_canvas(image, m.shape, "overlay_mask")
    grown = m.astype(np.uint8)
    if r > 0:
        grown = cv2.dilate(grown, np.ones((2 * r + 1, 2 * r + 1), np.uint8), borderType=cv2.BORDER_CONSTANT,
                           borderValue=0)
    out[grown > 0] = rgb.astype(np.uint8)
    return out


def nice_ticks(lo: float, hi: float, *, max_ticks: int = 7) -> np.ndarray:
    """Round tick values (1, 2 or 5 times a power of ten apart) inside [lo, hi]; at most ``max_ticks``."""
    if not (np.isfinite(lo) and np.isfinite(hi)) or hi < lo:
        raise ValueError(f"nice_ticks: expected finite lo <= hi, got {lo!r}, {hi!r}")
    if hi == lo:
        return np.array([lo], np.float64)
    raw = (hi - lo) / max(1, max_ticks - 1)
    power = 10.0 ** np.floor(np.log10(raw))
    for mult in (1.0, 2.0, 5.0, 10.0):
        step = mult * power
        if (hi - lo) / step <= max_ticks - 1:
            break
    first = np.ceil(lo / step - 1e-9) * step
    ticks = first + step * np.arange(int(np.floor((hi - first) / step + 1e-9)) + 1)
    return np.round(ticks, 10)


def _tick_label(value: float) -> str:
    text = f"{value:.2f}".rstrip("0").rstrip(".")
    return f"{'0' if text == '-0' else text} m"


def depth_preview(depth, *, vmin: float | None = None, vmax: float | None = None, cmap: str = "turbo",
                  invert: bool = False, bar_height_px: int = 36) -> np.ndarray:
    """:func:`colorize_depth` with a depth scale bar underneath (tick labels in metres, OpenCV text).

    Args:
      depth: (H, W) depth, metres; ``<= 0`` or non-finite = empty (black).
      vmin, vmax, cmap, invert: as :func:`colorize_depth`; the default range is the
        minimum / maximum valid depth (0 to 1 m for an image with no valid pixel).
      bar_height_px: height of the strip added below the image: a colour ramp of
        the range (left = ``vmin``) in its upper third, ticks at round depths
        (:func:`nice_ticks`) and their labels (``cv2.putText``) below it.

    Returns:
      (H + bar_height_px, W, 3) uint8 RGB: rows ``[:H]`` equal ``colorize_depth``
      with the same range; the bar's column ``x`` shows the colour of depth
      ``vmin + (vmax - vmin) * x / (W - 1)``.
    """
    d = np.asarray(depth, dtype=np.float32)
    if d.ndim != 2:
        raise ValueError(f"depth_preview: field 'depth' expected shape (H, W), got {d.shape}")
    if isinstance(bar_height_px, bool) or int(bar_height_px) != bar_height_px or bar_height_px < 12:
        raise ValueError(f"depth_preview: field 'bar_height_px' expected an integer >= 12, got {bar_height_px!r}")
    valid = np.isfinite(d) & (d > 0)
    lo = (float(d[valid].min()) if valid.any() else 0.0) if vmin is None else float(vmin)
    hi = (float(d[valid].max()) if valid.any() else 1.0) if vmax is None else float(vmax)
    if not hi >= lo:
        raise ValueError(f"depth_preview: field 'vmax' expected >= vmin ({lo}), got {hi}")
    h, w = d.shape
    image = colorize_depth(d, vmin=lo, vmax=hi, cmap=cmap, invert=invert)
    bar = np.zeros((int(bar_height_px), w, 3), np.uint8)
    ramp_h = max(4, int(bar_height_px) // 3)
    t = np.arange(w, dtype=np.float64) / max(1, w - 1)
    idx = np.rint(t * 255.0).astype(np.int64)
    if invert:
        idx = 255 - idx
    bar[1:1 + ramp_h] = colormap_lut(cmap)[idx][None]
    span = hi - lo
    font, scale, thick = cv2.FONT_HERSHEY_SIMPLEX, 0.35, 1
    y_text = int(bar_height_px) - 3
    right_edge = -10**9  # right end of the last label drawn
    for tick in nice_ticks(lo, hi, max_ticks=max(2, min(7, w // 60))):
        x = 0 if span <= 0 else int(round((tick - lo) / span * (w - 1)))
        cv2.line(bar, (x, 1 + ramp_h), (x, ramp_h + 4), (255, 255, 255), 1)
        label = _tick_label(float(tick))
        (tw, _), _ = cv2.getTextSize(label, font, scale, thick)
        left = min(max(0, x - tw // 2), max(0, w - tw))
        if left <= right_edge + 4:  # would overlap the previous label
            continue
        cv2.putText(bar, label, (left, y_text), font, scale, (255, 255, 255), thick, cv2.LINE_AA)
        right_edge = left + tw
    return np.concatenate([image, bar], axis=0)
