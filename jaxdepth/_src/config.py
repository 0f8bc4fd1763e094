"""SGMConfig: every tunable constant of the Surface Geometry Model, in one frozen place.

The config is hashable and passed as a jit static argument: changing a field
recompiles, changing data (depths, K, T_cam_lidar) does not. Calibration lives
in :class:`~jaxdepth.Camera`, never here.
"""

from __future__ import annotations

import dataclasses

#: The nearest-seed metrics (``SGMConfig.distance_metric``, ``nearest_seed(metric=)``, ``seed_distance``).
DISTANCE_METRICS = ("l1", "l2")
_OUTLIER_TESTS = ("footprint", "paper")
#: Step 4's choices above the top scan line (``SGMConfig.above_scan``).
ABOVE_SCAN = ("auto", "plane", "background", "capped")
#: When rule 6 of the multi-source path runs (``SGMConfig.reference_top_line``).
REFERENCE_TOP_LINE = ("auto", "on", "off")
#: Step 2 with several sweeps (``SGMConfig.outlier_sweeps``).
OUTLIER_SWEEPS = ("auto", "each", "merged")
#: Condition 1 for the older sweeps' points in Step 2 (``SGMConfig.older_sweeps_test``).
OLDER_SWEEPS_TESTS = ("footprint", "paper")


# (field, note) of the float options that must be >= 0
_NON_NEGATIVE_FIELDS = (("epsilon_m", ""), ("smoothing_sigma_px", ""), ("guidance_weight", " (0 = off)"),
                        ("guidance_noise_floor", ""), ("free_space_noise_m", ""), ("free_space_slope", ""),
                        ("occlusion_max_baseline_m", ""),
                        ("free_space_witness_cell", " (0 = the source's LidarSpec)"))


@dataclasses.dataclass(frozen=True)
class SGMConfig:
    """Constants of the four SGM steps. Defaults follow the paper where it gives a value.

    Attributes:
      outlier_removal: run Step 2 (the paper's Algorithm 1).
      outlier_test: condition 1 of Algorithm 1. "footprint" (default): point i
        is removed only if, between the LiDAR's view and the camera's, it passes
        behind a nearer point j through j's own footprint (a W L / N by H / L
        cell): the paper's order flip measured along the direction of the
        parallax, for any mounting. "paper": the paper's axis-aligned flips
        (u order vs azimuth or v order vs elevation) anywhere in S(i), which
        assume a LiDAR beside the camera.
      epsilon_m: Algorithm 1's depth margin epsilon, metres (paper: 1.0 m).
      outlier_max_half_width_px: static cap on the horizontal half window. The
        paper's bound |du| < W*L/N is computed at run time from the number N of
        projected points; offsets beyond this cap are never visited.
      outlier_max_half_height_px: static cap on the vertical half window. The
        paper's bound |dv| < H/L is static (image height, beam count).
      distance_metric: "l1" (city block, exact; the default) or "l2" (exact
        Euclidean: the nearest LiDAR pixel in the image plane). The paper's
        Appendix measures l1 distances and cites Rosenfeld and Pfaltz's city-block
        transform, as the authors' code does. l1 is the faster transform and, on
        held-out KITTI frames, also the more accurate (benchmarks/results:
        distance.json, accuracy_kitti_l2.json).
      seed_horizontal_cost: beyond the paper; an integer >= 1, "l1" and unguided only.
        Step 3's seed minimises ``seed_horizontal_cost |du| + |dv|``: one pixel of
        horizontal offset costs that many pixels of vertical offset. 1 (the default)
        is the paper's city block. Larger values take a seed straight above or below,
        across the gap between two scan lines, over one far to the side on a nearer
        line, which moves where a depth edge between scan lines falls
        (benchmarks/studies/edge_side.py, docs/evaluation.md).
      normal_smoothing: half width of the box filter that smooths normals on
        the range image (0 disables). The paper fills and smooths normals so
        every point has one.
      range_fill_max_gap: empty range-image cells up to this many columns from a
        measured cell borrow its range when computing derivatives.
      min_abs_denom: the residual's denominator n . ((u-pu)/fu, (v-pv)/fv, 1)
        below this magnitude (surface seen within ~0.6 degrees of grazing) gives
        Delta z = 0 (finite values and gradients). The road seen from 1.65 m has
        a denominator of about 1.65 / distance, so 0.01 keeps the residual up to
        ~165 m; 0.05 would switch it off beyond ~33 m.
      max_residual_ratio: |Delta z| is clipped to this fraction of z'.
      column_bracket: beyond the paper. Each pixel's plane
        prediction is clipped to the depth range of its nearest kept LiDAR
        pixels straight above and below, when both lie within the paper's
        vertical window H / L (one scan-line spacing): on a plane the depth
        between two of its points along an image column lies between theirs
        (:mod:`~jaxdepth._src.hypotheses`). False gives the paper's Step 4.
      blend_hypotheses: beyond the paper. Also average in the
        plane predictions of those two column neighbours, where they fall in
        the bracket, weighted by 1 / image distance to each seed. Needs
        ``column_bracket``.
      above_scan: beyond the paper. What Step 4 writes above the top scan line
        (above every kept LiDAR pixel of the columns within |du| < W L / N).
        "plane": the paper's nearest-seed plane. "background": the farthest
        seed depth among the row's pixels within |du| < W L / N (the paper's
        window of Algorithm 1), with no plane extrapolation: the top laser hit
        the bottom of what stands there, and the near things end above it while
        the background continues (:mod:`~jaxdepth._src.above_scan`). "capped":
        the nearest-seed plane followed at most one scan-line spacing (h / L
        rows, the column bracket's window) above the seed, held constant
        beyond (:func:`~jaxdepth._src.above_scan.capped_above_scan`). "auto" (default): "capped"
        where the reference sweep is several LiDARs scanning in lines (an Argoverse 2 rig's two
        VLP-32C), "plane" otherwise (one LiDAR: every single-sweep call, KITTI, nuScenes, a raster
        or rosette unit; :func:`~jaxdepth._src.above_scan.above_scan_rule`). Chosen on the twins
        (docs/method.md, "Per sensor class").
      smoothing_sigma_px: Gaussian sigma of Step 4's smoothing, pixels (0 disables).
        The paper gives no value; the default 1.4 with radius 3 is OpenCV's
        ``GaussianBlur(depth, (7, 7), 0)``.
      smoothing_radius_px: Gaussian kernel half width, pixels (kernel 2r+1).
      keep_measured_depth: LiDAR pixels kept by Step 2 keep their measured depth
        in the output (after smoothing).
      min_depth_m, max_depth_m: output clip range, metres.
      guidance_weight: image-guided seeds (beyond the paper). 0 (the
        default) is the paper's LiDAR-only seed search and ignores any image.
        > 0 needs a camera image: each pixel's seed minimises the geodesic
        distance where a 4-connected step costs 1 pixel plus this weight times
        the Euclidean colour difference (colours in [0, 1]), so seeds do not
        cross image edges (:mod:`~jaxdepth._src.geodesic`). Unit: pixels per
        unit of colour difference.
      guidance_sweeps: raster sweeps of the geodesic transform (each a
        horizontal and a vertical forward/backward pass); s sweeps are exact for
        paths of up to 2 s alternating straight runs.
      guidance_noise_floor: colour differences up to this many times the
        image's median step difference (its noise and texture level) cost
        nothing; a step pays ``guidance_weight`` only for the excess. 0 (the
        default) is GeoS's plain cost. At 1 it helps the synthetic renders and
        not the real KITTI and nuScenes images
        (benchmarks/results/ablation_guided_noise_floor.json), so it stays off.

    Several LiDARs and sweeps (:mod:`~jaxdepth._src.sources`, ``docs/multi_source.md``; beyond
    the paper, unused by single-origin completion):

      free_space_noise_m: range noise and registration error allowed for before a point of
        another sweep counts as lying in space a LiDAR saw empty, metres.
      free_space_slope: surface slope allowance of the free-space margin: the margin adds this
        many times ``range * gap``, ``gap`` the angular gap between the witness's neighbouring
        lasers at the point's elevation (or its horizontal step, if larger), radians; a surface
        at 45 degrees to the ray changes range by ``range * gap`` across one gap.
      free_space_min_cells: measured cells (of the 2 x 2 whose rays bracket a point) needed
        before a LiDAR's view there counts as evidence (1 to 4).
      free_space_neighbour_sweeps: sweeps on each side whose points a LiDAR of a sweep other
        than the reference and end sweeps judges for free space; None: every other sweep (cost
        quadratic in the sweeps); 0 (default): none (the end sweeps' witnesses already give
        what the neighbours add, docs/multi_source.md).
      occlusion_max_baseline_m: largest distance from a camera to the reference-sweep LiDAR
        whose view stands in for the camera's in the occlusion test of other sweeps' points,
        metres; for a camera farther from every such LiDAR the test is skipped.
      free_space_witness_cell: for a source with neither a stated LidarSpec nor laser rows (a
        raster or rosette unit), the side of its free-space witness grid's square cells in mean
        point spacings of its own scan (``jaxdepth.batch.sources_job.scan_witness_spec``); 0: the
        rig's LidarSpec grid, as for every other source.
      reference_top_line: in each camera image, the pixels of other sweeps' points that lie above the
        reference sweep's top scan line (no kept reference-sweep pixel at or above their row in the
        columns within the paper's window ``|du| < W L / N``) and nearer, by more than ``epsilon_m``,
        than the farthest top reference pixel of those columns are no seeds
        (:func:`~jaxdepth._src.above_scan.top_line_keep`). ``"auto"`` (default): on where the
        reference sweep is ONE source whose scan fills its own range-image rows (a spinning LiDAR, or a
        merged raster scan dense enough for its spec's grid: its top row is a scan line), off for
        several reference-sweep LiDARs and for a scan too sparse for that grid (a rosette, which gets
        a free-space grid of its own); ``"on"`` / ``"off"`` force it. Chosen on the twins: it wins on
        the KITTI, nuScenes and raster twins and loses on the Argoverse 2 (two LiDARs) and rosette
        twins (docs/multi_source.md, rule 6). One sweep is never affected.
      outlier_sweeps: Step 2 with several sweeps. ``"each"``: besides the pass over the merged image,
        each sweep's pixels are also judged as the one-sweep path judges one sweep: Algorithm 1 on the
        image of the reference sweep's pixels and that sweep's, removing only that sweep's, with one
        sweep's window (``N`` of ``W L / N``: the reference sweep's pixels, as ``L`` counts one sweep's
        beams); the reference sweep on its own pixels alone. ``"merged"``: the merged pass alone, whose
        ``N`` counts every sweep's pixels (``S`` sweeps make its window ``S`` times narrower while
        ``H / L`` stays). ``"auto"`` (default): ``"each"`` where a reference-sweep source is a scan
        without scan lines, too sparse for its spec's grid (a rosette: it gets a free-space grid of
        its own point spacing, :attr:`Sources.witnesses`), whose extra sweeps fill the image in two
        dimensions; ``"merged"`` for LiDARs scanning in lines, whose extra sweeps re-sample the same
        lines (:func:`~jaxdepth._src.sources.per_sweep_applies`). Chosen on the twins
        (docs/multi_source.md, "Step 2 per sweep"). One sweep is never affected.
      older_sweeps_test: condition 1 for the points of sweeps other than the reference sweep.
        ``"footprint"`` (default): as every point, by ``outlier_test``. ``"paper"``: they are also
        judged by the paper's axis-aligned flips in the same window, from their own origin and with
        the same epsilon (a second pass over the merged image, removing only older sweeps' pixels;
        with ``outlier_test="paper"`` nothing more). An older sweep's point is one of several
        samples of its surface, so a wrong removal costs little, while the paper form removes
        background points seen over a near object's top edge that the footprint form keeps
        (docs/multi_source.md, "Older sweeps by the paper form"). Not the default: it wins on the
        nuScenes twin and loses on the KITTI, raster and rosette twins and real Argoverse 2. One sweep
        is never affected.
    """

    outlier_removal: bool = True
    outlier_test: str = "footprint"
    epsilon_m: float = 1.0
    outlier_max_half_width_px: int = 12
    outlier_max_half_height_px: int = 24
    distance_metric: str = "l1"
    seed_horizontal_cost: int = 1
    normal_smoothing: int = 1
    range_fill_max_gap: int = 2
    min_abs_denom: float = 0.01
    max_residual_ratio: float = 0.5
    column_bracket: bool = True
    blend_hypotheses: bool = False
    above_scan: str = "auto"
    smoothing_sigma_px: float = 1.4
    smoothing_radius_px: int = 3
    keep_measured_depth: bool = True
    min_depth_m: float = 0.1
    max_depth_m: float = 150.0
    guidance_weight: float = 0.0
    guidance_sweeps: int = 2
    guidance_noise_floor: float = 0.0
    free_space_noise_m: float = 0.3
    free_space_slope: float = 2.0
    free_space_min_cells: int = 3
    free_space_neighbour_sweeps: int | None = 0
    occlusion_max_baseline_m: float = 1.0
    free_space_witness_cell: float = 2.0
    reference_top_line: str = "auto"
    outlier_sweeps: str = "auto"
    older_sweeps_test: str = "footprint"

    def __post_init__(self):
        if self.distance_metric not in DISTANCE_METRICS:
            raise ValueError(
                f"SGMConfig: field 'distance_metric' expected one of {DISTANCE_METRICS}, "
                f"got {self.distance_metric!r}")
        if self.outlier_test not in _OUTLIER_TESTS:
            raise ValueError(
                f"SGMConfig: field 'outlier_test' expected one of {_OUTLIER_TESTS}, got {self.outlier_test!r}")
        if self.above_scan not in ABOVE_SCAN:
            raise ValueError(f"SGMConfig: field 'above_scan' expected one of {ABOVE_SCAN}, got {self.above_scan!r}")
        if self.reference_top_line not in REFERENCE_TOP_LINE:
            raise ValueError(f"SGMConfig: field 'reference_top_line' expected one of {REFERENCE_TOP_LINE}, "
                             f"got {self.reference_top_line!r}")
        if self.outlier_sweeps not in OUTLIER_SWEEPS:
            raise ValueError(f"SGMConfig: field 'outlier_sweeps' expected one of {OUTLIER_SWEEPS}, "
                             f"got {self.outlier_sweeps!r}")
        if self.older_sweeps_test not in OLDER_SWEEPS_TESTS:
            raise ValueError(f"SGMConfig: field 'older_sweeps_test' expected one of {OLDER_SWEEPS_TESTS}, "
                             f"got {self.older_sweeps_test!r}")
        for name, note in _NON_NEGATIVE_FIELDS:  # `not >= 0` also refuses NaN
            value = getattr(self, name)
            if not value >= 0:
                raise ValueError(f"SGMConfig: field {name!r} expected >= 0{note}, got {value!r}")
        if not 0 < self.min_depth_m < self.max_depth_m:
            raise ValueError(
                "SGMConfig: fields 'min_depth_m' < 'max_depth_m' expected positive and ordered, "
                f"got {self.min_depth_m!r}, {self.max_depth_m!r}")
        for name in ("outlier_max_half_width_px", "outlier_max_half_height_px",
                     "smoothing_radius_px", "normal_smoothing", "range_fill_max_gap"):
            value = getattr(self, name)
            if int(value) != value or value < 0:
                raise ValueError(f"SGMConfig: field {name!r} expected a non-negative integer, got {value!r}")
        if isinstance(self.guidance_sweeps, bool) or int(self.guidance_sweeps) != self.guidance_sweeps \
                or self.guidance_sweeps < 1:
            raise ValueError(
                f"SGMConfig: field 'guidance_sweeps' expected an integer >= 1, got {self.guidance_sweeps!r}")
        c = self.seed_horizontal_cost
        if isinstance(c, bool) or int(c) != c or c < 1 or (c != 1 and (self.distance_metric != "l1"
                                                                       or self.guidance_weight > 0)):
            raise ValueError("SGMConfig: field 'seed_horizontal_cost' expected an integer >= 1 (1 unless "
                             f"distance_metric 'l1' and guidance_weight 0), got {c!r}")
        if self.blend_hypotheses and not self.column_bracket:
            raise ValueError("SGMConfig: field 'blend_hypotheses' expected with column_bracket=True "
                             "(the blend keeps only hypotheses inside the bracket), got column_bracket=False")
        if isinstance(self.free_space_min_cells, bool) or int(self.free_space_min_cells) != self.free_space_min_cells \
                or not 1 <= self.free_space_min_cells <= 4:
            raise ValueError("SGMConfig: field 'free_space_min_cells' expected an integer in 1..4, "
                             f"got {self.free_space_min_cells!r}")
        n = self.free_space_neighbour_sweeps
        if n is not None and (isinstance(n, bool) or int(n) != n or n < 0):
            raise ValueError(f"SGMConfig: field 'free_space_neighbour_sweeps' expected None or an integer >= 0, "
                             f"got {n!r}")
        if self.min_abs_denom <= 0:
            raise ValueError(f"SGMConfig: field 'min_abs_denom' expected > 0, got {self.min_abs_denom!r}")

    def replace(self, **changes) -> "SGMConfig":
        return dataclasses.replace(self, **changes)


#: The configuration every stage and entry point defaults to (the paper's values where it gives one).
DEFAULT_CONFIG = SGMConfig()
