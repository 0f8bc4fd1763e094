"""The parallax cover test from each target's own LiDAR origin (issue 37, coverscan3).

    PYTHONPATH=. python -m benchmarks.studies.cover_scan3 [--rigs av2] [--scales 0.5] [--scene-seeds 0 1] \
        [--hidden-seeds 0 1 2] [--json benchmarks/results/cover_scan3_coverscan3_av2_half.json]
    PYTHONPATH=. python -m benchmarks.studies.cover_scan3 --merge a.json b.json --json out.json

:mod:`benchmarks.studies.cover_scan2`'s parallax test (``parallax_w{w}_k{k}``, every target's direction and
shift from the reference sweep's first LiDAR origin) beside ``own_parallax_w{w}_k{k}``: the same test with
each target's direction and shift from the origin of the LiDAR its point came from (Argoverse 2's twin: two
LiDARs, the second upside down). That LiDAR is read from the input cloud's per-point ``source`` and its pose
``T_ref_source`` only (what a user's input carries): per camera, a z-buffer of the held-out points of each
source, a target pixel taking the source whose point is nearest there (the z-buffer's own point). The
occluder Q enters the test by its depth only (its shift is along the target's ray), so no occluder origin is
needed. On a one-LiDAR rig both tests are the same masks (tests/test_cover_scan3.py). Variants: those of
:mod:`benchmarks.studies.cover_tests` (``all``, ``both_sides`` = ``uncovered``, ...) and the two parallax
families; pair agreement with the exact depth, dense and at every held-out pixel, as coverscan2.
"""

from __future__ import annotations

import time

import numpy as np

from benchmarks._common import RESULTS, write_results
from benchmarks.studies import cover_scan, cover_scan2, cover_tests
from jaxdepth._src.config import SGMConfig

PARALLAX = tuple(f"{pre}parallax_w{w}_k{k}" for pre in ("", "own_") for w, k in ((1, "1"), (1, "0.5"), (2, "1")))
VARIANTS = cover_tests.VARIANTS + PARALLAX


def source_maps(points, source, rig) -> list:
    """Each camera's (H_i, W_i) int: the source (LiDAR index) of the nearest of ``points`` at each pixel
    (0 where none), from one z-buffer per source (ties: the lower index)."""
    from benchmarks.accuracy_twins import z_buffers
    per = [z_buffers(points[source == s], rig) for s in range(int(source.max()) + 1 if len(source) else 1)]
    out = []
    for i in range(len(rig.cameras)):
        stack = np.stack([np.where(b[i] > 0, b[i], np.inf) for b in per])
        out.append(np.argmin(stack, axis=0).astype(np.int64))
    return out


def add_parallax(masks, targets, full, wrong, inp, hidden, half, draw, preds, exact) -> None:
    """``cover_tests.run_twin``'s hook: both parallax families (w = 1, 2; k = 0.5, 1) on every camera."""
    c = inp.cloud
    sources = source_maps(c.points[hidden], c.source[hidden], inp.rig)
    reach = max(3, 3 * int(half))
    for m, t, f, s, cam in zip(masks, targets, full, sources, inp.rig.cameras):
        for width in (1, 2):
            first = cover_scan2.parallax_cover(t, f, cam.K, cam.T_cam_lidar, c.origins_m[0], (0.5, 1), reach, width)
            own = cover_scan2.parallax_cover(t, f, cam.K, cam.T_cam_lidar, c.origins_m, (0.5, 1), reach, width,
                                             source=s)
            for k in (0.5, 1):
                m[f"parallax_w{width}_k{k:g}"] = first[k]
                m[f"own_parallax_w{width}_k{k:g}"] = own[k]
    n = sum(int((t > 0).sum()) for t in targets)
    draw["second_source_target_share"] = sum(int(((s > 0) & (t > 0)).sum()) for s, t in zip(sources, targets)) / max(n, 1)


def main(argv=None) -> int:
    parser = cover_tests.study_parser(__doc__.splitlines()[0], ("av2",), (0.5,),
                                      RESULTS / "cover_scan3_coverscan3_av2_half.json")
    args = parser.parse_args(argv)
    t0 = time.time()
    config = SGMConfig()
    cases, merged_from = cover_tests.collect_cases(args, parser, config, t0, VARIANTS, add_parallax)
    doc = {"settings": {"sweeps": 1, "fraction": 0.2, "min_range_m": 1.0, "variants": list(VARIANTS),
                        "scales": {c["rig"]: c["scale"] for c in cases},
                        "scene_seeds": sorted({c["scene_seed"] for c in cases}),
                        "hidden_seeds": sorted({d["hidden_seed"] for c in cases for d in c["held_out"]})},
           "summary": cover_tests.summarise(cases, VARIANTS),
           "held_out_agreement": cover_scan.held_out_agreement(cases, VARIANTS),
           "seed_agreement": cover_scan2.seed_agreement(cases, VARIANTS),
           "second_source_target_share": {f'{c["rig"]}/{c["scene_seed"]}': float(np.mean([d["second_source_target_share"]
                                                                   for d in c["held_out"]])) for c in cases},
           "cases": cases}
    if merged_from:
        doc["merged_from"] = merged_from
    print("per twin: wrong / right dropped; agreement, dense (per scene seed) and at the held-out pixels:")
    print(cover_scan2.twin_table(doc, ("all", "both_sides") + PARALLAX))
    write_results(args.json, cover_scan2.slim(doc), config, t0, indent=None)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
