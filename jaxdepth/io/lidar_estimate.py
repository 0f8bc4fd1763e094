"""What a sweep says about the LiDAR that recorded it (host side, NumPy).

A spinning multi-beam LiDAR fires each beam at a fixed elevation while it
turns about its vertical axis, so seen from the sensor's own position every
beam's points share one elevation angle: the elevations cluster into L sharp
rings. Seen from another position (a vehicle origin on the ground 1.5-2 m
away) near points shift by roughly offset / range radians and the rings smear.
:func:`estimate_lidar_geometry` judges a sweep at its points' origin:

- with ring (beam) indices (nuScenes' 5th column): the rings are tight when at
  most :data:`TIGHT_RINGS` of the elevation variance lies within rings; the
  beam count is the number of rings and the vertical field of view runs from
  the highest to the lowest ring's median elevation;
- without them: the share of points within 0.15 degrees of a peak of the
  elevation histogram (:data:`MIN_ON_PEAKS`);
- in both cases the sweep must cover the full turn of azimuth (a rosette or
  raster scan does not), and the ground must lie at least
  :data:`MIN_SENSOR_HEIGHT_M` below (or above) the origin: a vehicle frame's
  origin on the road is no sensor position (dense 64-beam rings pass the
  histogram test even from a wrong origin).

It does not move the origin: searching the position that tightens the rings
found look-alike optima on real sweeps (the HDL-32E's lasers do not share one
optical centre: the tightest rings of the nuScenes sample sit 24 cm from its
frame's origin; without rings an origin on the ground plane puts every ground
point on one "ring"). A sweep that is not one spinning LiDAR around its points'
origin (a vehicle frame, a merged cloud, a non-spinning scan) is reported as
such, and :func:`jaxdepth.io.prepare_sweep` then turns outlier removal off
unless the rig states where the sensor sits (``lidar.origin_m``).

Assumption: the spin axis is the points frame's z axis (upright sensor).
Known limit: without ring indices a merged cloud whose sensors sit close
together can still look like one spinning LiDAR.
"""

from __future__ import annotations

import dataclasses

import numpy as np

#: Elevation histogram bin, degrees.
BIN_DEG = 0.05
#: Rings are tight (the sweep is in its sensor's frame) when this share of the elevation variance or
#: less lies within rings (nuScenes sample at its own origin: 0.0012; 1.9 m away: 0.25).
TIGHT_RINGS = 0.01
#: Share of points that must sit within PEAK_TOL_DEG of a peak for a spinning LiDAR.
MIN_ON_PEAKS = 0.65
PEAK_TOL_DEG = 0.15
#: Share of 5-degree azimuth sectors that must hold points for a spinning LiDAR.
MIN_AZIMUTH_COVER = 0.9
#: Ring tightness is judged on points farther than this, metres (near points show the lasers' offsets).
MIN_RANGE_M = 2.0
#: A LiDAR on a vehicle sits well above the road: a ground plane closer than this below (or above)
#: the points' origin means the origin is not the sensor (a vehicle frame on the ground), metres.
MIN_SENSOR_HEIGHT_M = 0.6


@dataclasses.dataclass(frozen=True)
class LidarEstimate:
    """What :func:`estimate_lidar_geometry` found.

    Attributes:
      origin_m: (3,) float64 sensor position in the points' frame, metres.
      beams: number of elevation peaks (None if the sweep is not one spinning LiDAR).
      fov_up_deg, fov_down_deg: elevations of the outermost peaks, degrees (or None).
      spinning: the sweep looks like one spinning multi-beam LiDAR around ``origin_m``.
      on_peaks: share of points within 0.15 degrees of a peak.
      azimuth_cover: share of 5-degree azimuth sectors with points.
      ground_z_m: height of the ground plane in the points' frame (the most common z among the
        lowest fifth of points 3-15 m away horizontally), or None if too few such points.
    """

    origin_m: np.ndarray
    beams: int | None
    fov_up_deg: float | None
    fov_down_deg: float | None
    spinning: bool
    on_peaks: float
    azimuth_cover: float
    ground_z_m: float | None = None

    def describe(self) -> str:
        where = "(" + ", ".join(f"{x:+.2f}" for x in self.origin_m) + ") m"
        if not self.spinning:
            ground = "" if self.ground_z_m is None else f", ground at z = {self.ground_z_m:+.2f} m"
            return (f"not one spinning LiDAR around the points' origin ({100 * self.on_peaks:.0f} % of points "
                    f"on elevation rings, {100 * self.azimuth_cover:.0f} % of the azimuth covered{ground})")
        if self.beams is None:
            return (f"one spinning LiDAR at the points' origin {where} ({100 * self.on_peaks:.0f} % of points "
                    "on elevation rings; no ring indices for beams and field of view)")
        return (f"one spinning LiDAR at {where}, {self.beams} beams, elevation {self.fov_up_deg:+.2f} to "
                f"{self.fov_down_deg:+.2f} deg ({100 * self.on_peaks:.0f} % of points within "
                f"{PEAK_TOL_DEG} deg of their ring)")


def _elevation_deg(p: np.ndarray, origin) -> np.ndarray:
    q = p - np.asarray(origin, np.float64)
    return np.degrees(np.arctan2(q[:, 2], np.hypot(q[:, 0], q[:, 1])))


def ring_labels(ring) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique(ring, return_inverse=True)`` of a (n,) ring array: its sorted distinct values and each
    point's index among them, the same arrays. Integer rings of non-negative values below 65536 (laser
    numbers) are counted (bincount, one gather) instead of sorted; any other ring goes to ``np.unique``."""
    ring = np.asarray(ring)
    if (ring.ndim == 1 and ring.size and ring.dtype.kind in "iu" and np.can_cast(ring.dtype, np.intp)
            and ring.min() >= 0 and ring.max() < 1 << 16):
        present = np.bincount(ring) > 0
        return np.flatnonzero(present).astype(ring.dtype), (np.cumsum(present) - 1)[ring]
    return np.unique(ring, return_inverse=True)


def ring_medians(values: np.ndarray, inverse: np.ndarray, count: int) -> np.ndarray:
    """(count,) float64: ``np.median(values[inverse == i])`` for each ring index ``i < count`` (NaN where the
    ring has no value), the same numbers: one stable sort by ring (a radix sort of 16-bit indices) keeps each
    ring's values in their order, then a median per run instead of a mask over all values per ring."""
    inverse = np.asarray(inverse)
    keys = inverse.astype(np.uint16) if count <= 1 << 16 else inverse
    ordered = np.asarray(values)[np.argsort(keys, kind="stable")]
    sizes = np.bincount(inverse, minlength=count)
    ends = np.cumsum(sizes)
    return np.array([np.median(ordered[end - size:end]) if size else np.nan for size, end in zip(sizes, ends)],
                    np.float64)


def _ring_spread(el: np.ndarray, ring: np.ndarray) -> float:
    """Minus the share of elevation variance left within rings (scale free: a far-away origin
    squeezes every angle, within and between rings alike)."""
    labels, inverse = ring_labels(ring)
    sums = np.bincount(inverse, weights=el, minlength=labels.size)
    counts = np.bincount(inverse, minlength=labels.size).astype(np.float64)
    means = sums / np.maximum(counts, 1.0)
    within = float(np.sum((el - means[inverse]) ** 2))
    total = float(np.sum((el - el.mean()) ** 2))
    return -within / max(total, 1e-12)


def _on_peaks(el: np.ndarray) -> float:
    peaks = _peaks(el)
    if not peaks.size:
        return 0.0
    idx = np.clip(np.searchsorted(peaks, el), 1, max(peaks.size - 1, 1))
    lo = peaks[np.clip(idx - 1, 0, peaks.size - 1)]
    hi = peaks[np.clip(idx, 0, peaks.size - 1)]
    near = np.minimum(np.abs(el - lo), np.abs(el - hi)) <= PEAK_TOL_DEG
    return float(np.mean(near))


def _peaks(el: np.ndarray) -> np.ndarray:
    counts = np.bincount(np.floor((el + 90.0) / BIN_DEG).astype(np.int64).clip(0, int(180 / BIN_DEG)),
                         minlength=int(180 / BIN_DEG) + 1).astype(np.float64)
    smooth = np.convolve(counts, np.ones(3) / 3.0, mode="same")
    # A beam holds at least 1/512 of the points of its sweep (at most 256 beams, half of them weak).
    floor = max(3.0, el.size / 512.0 / 3.0)
    is_peak = (smooth > floor) & (smooth >= np.roll(smooth, 1)) & (smooth > np.roll(smooth, -1))
    centres = (np.nonzero(is_peak)[0] + 0.5) * BIN_DEG - 90.0
    merged = []
    for c in centres:
        if merged and c - merged[-1] < 2 * PEAK_TOL_DEG:
            continue
        merged.append(c)
    return np.asarray(merged)


def _ground_z(q: np.ndarray) -> float | None:
    """Most common z (5 cm bins) among the lowest fifth of the points 3-15 m away horizontally."""
    rho = np.hypot(q[:, 0], q[:, 1])
    z = q[(rho > 3.0) & (rho < 15.0), 2]
    if z.size < 200:
        return None
    low = z[z <= np.quantile(z, 0.2)]
    bins = np.floor(low / 0.05).astype(np.int64)
    values, counts = np.unique(bins, return_counts=True)
    return float((values[int(np.argmax(counts))] + 0.5) * 0.05)


def estimate_lidar_geometry(points: np.ndarray, *, ring: np.ndarray | None = None) -> LidarEstimate:
    """Sensor position, beam count and vertical field of view of one sweep (see the module docstring).

    Args:
      points: (N, >= 3) points, metres (extra columns and non-finite rows are ignored).
      ring: optional (N,) beam index per point (e.g. nuScenes' 5th column).

    Returns:
      :class:`LidarEstimate`. Deterministic: the same sweep gives the same estimate.
    """
    p = np.asarray(points, np.float64)[:, :3]
    ok = np.all(np.isfinite(p), axis=1) & (np.linalg.norm(np.nan_to_num(p), axis=1) > 0.5)
    if ring is not None:
        ring = np.asarray(ring)
        ok &= np.isfinite(ring)
        ring = ring[ok]
    p = p[ok]
    if p.shape[0] < 100:
        return LidarEstimate(np.zeros(3), None, None, None, False, 0.0, 0.0)
    origin = np.zeros(3)
    el = _elevation_deg(p, origin)
    q = p - origin
    az = np.degrees(np.arctan2(q[:, 1], q[:, 0]))
    cover = float(np.mean(np.bincount(np.floor((az + 180.0) / 5.0).astype(np.int64).clip(0, 71),
                                      minlength=72) > 0))
    if ring is not None:
        labels, inverse = ring_labels(ring)
        centres = ring_medians(el, inverse, labels.size)
        on_peaks = float(np.mean(np.abs(el - centres[inverse]) <= PEAK_TOL_DEG))
        far = np.linalg.norm(q, axis=1) > MIN_RANGE_M
        tight = -_ring_spread(el[far], ring[far]) <= TIGHT_RINGS if far.sum() >= 100 else False
        on_peaks = max(on_peaks, MIN_ON_PEAKS) if tight else min(on_peaks, 0.0)
        beams = int(labels.size)
    else:
        on_peaks = _on_peaks(el)
        centres = _peaks(el)
        beams = int(centres.size)
    ground = _ground_z(q)
    above_ground = ground is None or abs(ground) >= MIN_SENSOR_HEIGHT_M
    spinning = bool(cover >= MIN_AZIMUTH_COVER and on_peaks >= MIN_ON_PEAKS and 4 <= beams <= 256 and above_ground)
    known = spinning and ring is not None
    return LidarEstimate(origin_m=origin, beams=beams if known else None,
                         fov_up_deg=float(centres.max()) if known else None,
                         fov_down_deg=float(centres.min()) if known else None,
                         spinning=spinning, on_peaks=on_peaks, azimuth_cover=cover,
                         ground_z_m=ground)


__all__ = ["LidarEstimate", "estimate_lidar_geometry", "ring_labels", "ring_medians"]
