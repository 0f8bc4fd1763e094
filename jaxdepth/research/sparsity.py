"""The paper's sparsity study (its Section V-A and Fig. 6): 64-, 32- and 16-line input.

Following Ma et al. ("Self-supervised Sparse-to-Dense", ICRA 2019) the paper
simulates sparser LiDARs by grouping the points of a 64-beam sweep by laser
beam and keeping every 2nd (32 lines) or 4th (16 lines) beam. The beam of a
point is recovered from its elevation angle here (:func:`beam_index`), so any
sweep works, whatever the order of its points; then :func:`subsample_beams`
keeps every ``keep_every``-th beam, :func:`simulated_lidar` describes the
sparser sensor, and :func:`sparsity_study` completes and scores each density.

Every sensor-dependent size follows from the :class:`~jaxdepth.LidarSpec`: the
range image has ``beams`` rows and the outlier window ``H / L`` uses the
simulated beam count, so 16-, 32-, 64- and 128-beam sensors need no code change.

Beam estimation (host side, NumPy; deterministic)
-------------------------------------------------
Each laser of a spinning LiDAR sweeps a cone. Measured from the LiDAR origin
the elevation ``phi = atan2(z, rho)`` of one cone's points is *not* constant:
the lasers sit above or below the origin (KITTI's HDL-64E: about 0.20 m for
the upper block, 0.11 m for the lower one), so ``phi`` drifts by about
``h / rho`` and near points of neighbouring beams (0.33 degrees apart) overlap.
:func:`beam_model` therefore measures the elevation from an apex ``(0, 0, h)``,
``tan phi' = (z - h) / rho``, and picks ``h`` on a grid (``apex_grid_m``) to
maximise the separation of the beams. The split: a histogram of ``phi'``
(``bin_deg`` bins); bins with fewer than ``noise_fraction * n / L`` points
count as empty (stray returns); the ``L - 1`` longest runs of empty bins
between occupied bins are the beam boundaries (cut at their middles). The
score is the total length of these gaps minus the total width of the groups
between them (ties: the smallest ``|h|``): a wrong apex smears each cone over a
band of elevations, widest for the near points, and the gaps alone can then
grow, as sparse smeared bins stretch the occupied span (an 8-beam cone sweep
with its apex 0.25 m up scored a 0.46 m-down apex higher). Points closer
than ``min_range_m`` (no-return placeholders near the origin, returns from the
vehicle) and invalid points get beam -1.

Measured (tests/test_sparsity.py):

* KITTI ``drive_0001_frame05`` (HDL-64E, stored ring by ring): the estimate
  agrees with the ring order read from the points' azimuth wrap-arounds for
  98.6 % of the points; 64 beams of 1,136 - 2,147 points (121,948 / 64 = 1,905
  on average); fitted apex 0.20 m. The linear field-of-view binning agrees
  for under 20 %.
* nuScenes sample (HDL-32E with a recorded ring index): 100 % for the upper 18
  beams, 83 % overall. The ground-facing beams of that sweep swing by up to 2
  degrees in elevation with azimuth, so neighbouring beams (1.33 degrees apart)
  overlap in elevation and no elevation-only method can split them; use the
  recorded ring index there when it exists.
* Synthetic sweeps (:func:`jaxdepth.make_street_scene`, exact cones from the
  origin): exact for 16 - 128 beams.

Reference and difference: Ma et al. bin the elevation angle into beams; the
linear binning of the field of view (``method="fov"``, the range-image rows)
is available, but is badly wrong for the HDL-64E, whose beams are not evenly
spaced (0.33 degrees in the upper block, 0.5 in the lower).
"""

from __future__ import annotations

import logging
import math
from typing import NamedTuple

import numpy as np

from jaxdepth._src.types import LidarSpec

log = logging.getLogger("jaxdepth")

METHODS = ("gaps", "fov")


class BeamModel(NamedTuple):
    """Result of :func:`beam_model`.

    Attributes:
      index: (N,) int32 beam of each point, 0 = highest elevation, -1 = invalid
        or closer than ``min_range_m``.
      beams_found: number of separated elevation groups (``lidar.beams`` unless
        whole beams returned nothing).
      apex_height_m: fitted height of the cone apex above the LiDAR origin.
      cuts_deg: (beams_found - 1,) float64 corrected elevations of the beam
        boundaries, descending.
      separation_deg: total length of the boundary gaps.
    """

    index: np.ndarray
    beams_found: int
    apex_height_m: float
    cuts_deg: np.ndarray
    separation_deg: float


def _check_lidar(lidar, where: str) -> LidarSpec:
    if not isinstance(lidar, LidarSpec):
        raise ValueError(f"{where}: field 'lidar' expected a LidarSpec, got {type(lidar).__name__}")
    return lidar


def _check_points(points, valid, where: str):
    points = np.asarray(points)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"{where}: field 'points' expected shape (N, 3), got {points.shape}")
    if valid is None:
        valid = np.ones(points.shape[0], bool)
    valid = np.asarray(valid)
    if valid.shape != (points.shape[0],):
        raise ValueError(f"{where}: field 'valid' expected shape ({points.shape[0]},), got {valid.shape}")
    return points.astype(np.float64), valid.astype(bool)


def _split(slope: np.ndarray, beams: int, bin_deg: float, min_count: int):
    """Beam boundaries of corrected slopes tan(phi'): (gaps_deg, widths_deg, cuts_deg descending).

    ``gaps_deg``: total length of the boundary gaps; ``widths_deg``: total width of the groups
    between them (the occupied span minus the gaps).
    """
    phi = np.degrees(np.arctan(slope))
    lo = float(phi.min())
    counts = np.bincount(np.floor((phi - lo) / bin_deg).astype(np.int64))
    occupied = np.flatnonzero(counts >= min_count)
    if occupied.size < 2 or beams < 2:
        return 0.0, 0.0, np.zeros(0)
    run = np.diff(occupied) - 1  # empty bins between consecutive occupied bins
    longest = np.argsort(-run, kind="stable")[:beams - 1]
    longest = longest[run[longest] > 0]
    cuts = lo + bin_deg * (occupied[longest] + 1 + 0.5 * run[longest])
    gaps = int(run[longest].sum())
    widths = int(occupied[-1] - occupied[0] + 1) - gaps
    return float(bin_deg * gaps), float(bin_deg * widths), np.sort(cuts)[::-1]


def _label(slope: np.ndarray, cuts_desc: np.ndarray) -> np.ndarray:
    """0 for the group above the first cut, 1 below it, ... (cuts descending)."""
    phi = np.degrees(np.arctan(slope))
    return np.searchsorted(-cuts_desc, -phi, side="right").astype(np.int32)


def beam_model(points: np.ndarray, valid: np.ndarray | None = None, *, lidar: LidarSpec,
               method: str = "gaps", min_range_m: float = 1.0, bin_deg: float = 0.01,
               noise_fraction: float = 0.01, apex_grid_m: tuple[float, float, float] = (-0.5, 0.5, 0.01)) -> BeamModel:
    """Estimates the laser beam of every point of a sweep from its elevation (see module docs).

    Args:
      points: (N, 3) real LiDAR-frame points, metres.
      valid: optional (N,) bool; False points get beam -1.
      lidar: the sensor (``lidar.beams`` groups are sought; ``method="fov"`` also
        uses its field of view).
      method: "gaps" (robust, default) or "fov" (row of the linear range image,
        ``floor((fov_up - phi) / (fov_up - fov_down) * L)`` clipped, as
        :func:`jaxdepth.range_image`; apex and tilt are 0).
      min_range_m: points closer than this (3-D range) get beam -1.
      bin_deg: elevation histogram bin, degrees.
      noise_fraction: bins with fewer than ``noise_fraction * n / beams`` points
        are treated as empty.
      apex_grid_m: (start, stop, step) of the apex heights tried, metres.

    Returns:
      :class:`BeamModel` (``index`` is (N,) int32).

    Raises:
      ValueError: bad shapes or options, or no point at range >= ``min_range_m``.
    """
    where = "beam_model"
    lidar = _check_lidar(lidar, where)
    pts, valid = _check_points(points, valid, where)
    if method not in METHODS:
        raise ValueError(f"{where}: field 'method' expected one of {METHODS}, got {method!r}")
    if not bin_deg > 0 or not noise_fraction >= 0 or not min_range_m >= 0:
        raise ValueError(f"{where}: expected bin_deg > 0, noise_fraction >= 0, min_range_m >= 0, "
                         f"got {bin_deg!r}, {noise_fraction!r}, {min_range_m!r}")
    start, stop, step = (float(v) for v in apex_grid_m)
    if not (step > 0 and stop >= start):
        raise ValueError(f"{where}: field 'apex_grid_m' expected (start, stop >= start, step > 0), got {apex_grid_m!r}")
    with np.errstate(invalid="ignore", over="ignore"):
        x, y, z = pts[:, 0], pts[:, 1], pts[:, 2]
        rho = np.hypot(x, y)
        ok = valid & np.isfinite(rho) & np.isfinite(z) & (np.hypot(rho, z) >= max(min_range_m, 1e-9)) & (rho > 0)
    index = np.full(pts.shape[0], -1, np.int32)
    if not ok.any():
        raise ValueError(f"{where}: field 'points' expected valid points at range >= {min_range_m} m, got none")
    L = int(lidar.beams)
    rho, z = rho[ok], z[ok]
    ratio, inv_rho = z / rho, 1.0 / rho

    if method == "fov":
        phi = np.arctan2(z, rho)
        span = lidar.fov_up_rad - lidar.fov_down_rad
        row = np.clip(np.floor((lidar.fov_up_rad - phi) * (L / span)), 0, L - 1).astype(np.int32)
        index[ok] = row
        return BeamModel(index, int(np.unique(row).size), 0.0, np.zeros(0), 0.0)

    min_count = max(2, int(math.ceil(noise_fraction * ok.sum() / L)))
    best = None
    for h in np.arange(round((stop - start) / step) + 1) * step + start:
        gaps, widths, cuts = _split(ratio - h * inv_rho, L, bin_deg, min_count)
        score = gaps - widths
        if best is None or score > best[0] + 1e-9 or (abs(score - best[0]) <= 1e-9 and abs(h) < abs(best[1])):
            best = (score, float(h), cuts, gaps)
    _, h, cuts, gaps = best
    index[ok] = _label(ratio - h * inv_rho, cuts)
    found = int(cuts.size + 1)
    if found < L:
        log.warning("beam_model: found %d separated elevation groups, expected %d beams; "
                    "groups are numbered from the top without gaps", found, L)
    return BeamModel(index, found, h, cuts, gaps)


def beam_index(points: np.ndarray, valid: np.ndarray | None = None, *, lidar: LidarSpec,
               **options) -> np.ndarray:
    """(N,) int32 beam of every point, 0 = highest, -1 = invalid or too close.

    ``beam_model(points, valid, lidar=lidar, **options).index``; see
    :func:`beam_model` for the options and the method.

    Example (a synthetic sweep is row major over (beam, column)):

    >>> import jaxdepth
    >>> lidar = jaxdepth.LidarSpec(beams=16, columns=256)
    >>> frame = jaxdepth.make_street_scene(0, lidar=lidar, cameras=())
    >>> b = beam_index(frame.points, frame.valid, lidar=lidar)
    >>> bool(np.all(b[frame.valid] == (np.arange(16 * 256) // 256)[frame.valid]))
    True
    """
    return beam_model(points, valid, lidar=lidar, **options).index


def subsample_beams(points: np.ndarray, valid: np.ndarray | None = None, *, lidar: LidarSpec, keep_every: int,
                    offset: int = 0, beam: np.ndarray | None = None) -> np.ndarray:
    """(N,) bool: the valid points of every ``keep_every``-th beam (beams ``offset``, ``offset + k``, ...).

    Args:
      points: (N, 3) LiDAR-frame points, metres.
      valid: optional (N,) bool.
      lidar: the sensor that recorded the sweep.
      keep_every: k >= 1 (1 keeps every beam; 2 simulates half the beams).
      offset: first kept beam, 0 <= offset < k (0 = the highest beam).
      beam: optional (N,) int beam indices (from :func:`beam_index`) to reuse.

    Returns:
      (N,) bool mask; points with beam -1 are dropped.
    """
    lidar = _check_lidar(lidar, "subsample_beams")
    if isinstance(keep_every, bool) or not isinstance(keep_every, (int, np.integer)) or keep_every < 1:
        raise ValueError(f"subsample_beams: field 'keep_every' expected an integer >= 1, got {keep_every!r}")
    if not 0 <= offset < keep_every:
        raise ValueError(f"subsample_beams: field 'offset' expected 0 <= offset < {keep_every}, got {offset!r}")
    pts, valid = _check_points(points, valid, "subsample_beams")
    if beam is None:
        beam = beam_index(pts, valid, lidar=lidar)
    beam = np.asarray(beam)
    if beam.shape != valid.shape:
        raise ValueError(f"subsample_beams: field 'beam' expected shape {valid.shape}, got {beam.shape}")
    return valid & (beam >= 0) & ((beam - offset) % keep_every == 0)


def simulated_lidar(lidar: LidarSpec, keep_every: int) -> LidarSpec:
    """The sensor that keeping every ``keep_every``-th beam simulates.

    Same field of view and columns, ``beams = ceil(lidar.beams / keep_every)``
    (``lidar.beams // keep_every`` when it divides).

    >>> from jaxdepth import KITTI_HDL64
    >>> simulated_lidar(KITTI_HDL64, 4).beams
    16
    """
    lidar = _check_lidar(lidar, "simulated_lidar")
    if isinstance(keep_every, bool) or not isinstance(keep_every, (int, np.integer)) or keep_every < 1:
        raise ValueError(f"simulated_lidar: field 'keep_every' expected an integer >= 1, got {keep_every!r}")
    return LidarSpec(beams=-(-int(lidar.beams) // int(keep_every)), fov_up_deg=lidar.fov_up_deg,
                     fov_down_deg=lidar.fov_down_deg, columns=lidar.columns)


def keep_every_for(lidar: LidarSpec, beams: int) -> int:
    """k such that keeping every k-th beam of ``lidar`` gives ``beams`` beams (must divide)."""
    if isinstance(beams, bool) or not isinstance(beams, (int, np.integer)) or beams < 1 or lidar.beams % beams:
        raise ValueError(f"sparsity: field 'beams' expected a divisor of the sensor's {lidar.beams} beams, "
                         f"got {beams!r}")
    return int(lidar.beams // beams)


def sparsity_study(points: np.ndarray, valid: np.ndarray | None, camera, gt: np.ndarray, *, lidar: LidarSpec,
                   beams=(64, 32, 16), config=None, beam: np.ndarray | None = None) -> dict:
    """Completion error of SGM and of the nearest fill for sparser simulated sensors.

    For each target beam count b (a divisor of ``lidar.beams``): keep every
    ``lidar.beams // b``-th beam (:func:`subsample_beams`), complete with
    :func:`jaxdepth.complete_points_stages` under the simulated
    :class:`LidarSpec` (``.depth`` is SGM, ``.seed_depth`` the nearest fill after
    the same outlier removal), and score both with :func:`jaxdepth.depth_metrics`.

    Args:
      points: (N, 3) LiDAR-frame points, metres. valid: (N,) bool or None.
      camera: :class:`jaxdepth.Camera` of the ground truth image.
      gt: (camera.height, camera.width) ground-truth depth, metres, 0 = none.
      lidar: the recording sensor. beams: target beam counts.
      config: :class:`SGMConfig` (default ``SGMConfig()``).
      beam: optional precomputed :func:`beam_index`.

    Returns:
      {"lidar_beams": int, "beams_found": int, "rows": {str(b): {"beams", "keep_every",
      "points", "input_pixels", "input_density", "sgm": {rmse, mae, irmse, imae},
      "nearest": {...}, "density": % of pixels with a prediction}}} (mm, 1/km, %).
    """
    import jax.numpy as jnp

    from jaxdepth._src.config import SGMConfig
    from jaxdepth._src.metrics import depth_metrics
    from jaxdepth._src.pipeline import complete_points_stages
    from jaxdepth.io.points import pad_points

    lidar = _check_lidar(lidar, "sparsity_study")
    config = SGMConfig() if config is None else config
    pts, valid = _check_points(points, valid, "sparsity_study")
    gt = np.asarray(gt, np.float32)
    if gt.shape != (camera.height, camera.width):
        raise ValueError(f"sparsity_study: field 'gt' expected shape {(camera.height, camera.width)}, got {gt.shape}")
    targets = [int(b) for b in beams]
    ks = [keep_every_for(lidar, b) for b in targets]
    found = None
    if beam is None:
        model = beam_model(pts, valid, lidar=lidar)
        beam, found = model.index, model.beams_found
    padded, pad_valid = pad_points(pts.astype(np.float32))
    n = pts.shape[0]
    rows = {}
    for b, k in zip(targets, ks):
        keep = subsample_beams(pts, valid, lidar=lidar, keep_every=k, beam=beam)
        mask = np.zeros(padded.shape[0], bool)
        mask[:n] = keep
        mask &= pad_valid
        stages = complete_points_stages(jnp.asarray(padded), jnp.asarray(mask), camera, config=config,
                                        lidar=simulated_lidar(lidar, k))
        size = gt.size
        sparse = np.asarray(stages.sparse_depth)
        row = {"beams": b, "keep_every": k, "points": int(keep.sum()),
               "input_pixels": int(np.count_nonzero(sparse > 0)),
               "input_density": 100.0 * np.count_nonzero(sparse > 0) / size,
               "density": 100.0 * np.count_nonzero(np.asarray(stages.depth) > 0) / size}
        for name, pred in (("sgm", stages.depth), ("nearest", stages.seed_depth)):
            m = depth_metrics(pred, jnp.asarray(gt))
            row[name] = {key: float(m[key]) for key in ("rmse", "mae", "irmse", "imae")}
        rows[str(b)] = row
    return {"lidar_beams": int(lidar.beams), "beams_found": found, "rows": rows}


def format_sparsity(result: dict) -> list:
    """Table lines: beams x (points, input density, SGM and nearest-fill RMSE / MAE, density)."""
    lines = [f"{'beams':>6s}{'points':>9s}{'input px':>10s}{'input %':>9s}"
             f"{'SGM RMSE':>10s}{'SGM MAE':>9s}{'NN RMSE':>9s}{'NN MAE':>8s}{'dense %':>9s}"]
    for row in result["rows"].values():
        s, nn = row["sgm"], row["nearest"]
        lines.append(f"{row['beams']:6d}{row['points']:9d}{row['input_pixels']:10d}{row['input_density']:9.2f}"
                     f"{s['rmse']:10.1f}{s['mae']:9.1f}{nn['rmse']:9.1f}{nn['mae']:8.1f}{row['density']:9.2f}")
    lines.append("RMSE / MAE in mm against the ground truth; NN = nearest fill after the same outlier removal")
    return lines


__all__ = ["BeamModel", "beam_model", "beam_index", "subsample_beams", "simulated_lidar", "keep_every_for",
           "sparsity_study", "format_sparsity"]
