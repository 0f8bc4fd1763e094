"""Why a rig camera's projection differed from its single-camera call (issue 37), and what the fix costs.

    PYTHONPATH=. python -m benchmarks.studies.projection_rounding [--rounds 5]
        [--json benchmarks/results/projection_rounding.json]

On the shared Argoverse 2 sweep (two VLP-32C as two sources, 131,072 points after padding; the six
2048 x 1550 ring cameras, the rig programs' one vmapped size group), two forms of the projection:

- ``plain``: the form before the fix, ``points @ R.T + t`` (:func:`geometry.transform_points`)
  then ``u = fx x/z + s y/z + cx``, ``v = fy y/z + cy`` in plain float32;
- ``fixed``: :func:`geometry.camera_points` and :func:`geometry.project_pixels` (every product
  from 12-bit halves: exact, so FMA contraction and the batched product cannot change the bits).

For each: the points whose u, v or z bits differ between the six cameras vmapped (the rig) and
each camera alone (its single-camera call), and those that round to another pixel (all points,
and those landing inside the image in either call). A group of two cameras as well: XLA:CPU
computes the batched rotation product with the unbatched kernel's rounding only up to two cameras.

Speed: the rig programs' projection stage (``pipeline.project_with_normals``: z-buffer, each
pixel's point and normal) vmapped over the six cameras, the form before the fix (per pixel
``transform_points`` of the winning point, as the code was) against the fixed one (each point
transformed once with exact products, then gathered), each jitted, ``--rounds`` interleaved
rounds, medians and the per-round ratio; compile apart (first call).
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import jax
import jax.numpy as jnp
import numpy as np

from benchmarks._common import DATA, RESULTS, write_results

LOG = DATA / "av2" / "sensor" / "val" / "7fab2350-7eaf-3b7e-a39d-6937a4c1bede"


def _plain_uv(points, K, T):
    """The projection before the fix: plain float32 product and pixel formula."""
    from jaxdepth._src.geometry import transform_points
    p = transform_points(T, points)
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    zs = jnp.where(z > 0.1, z, 1.0)
    return K[0, 0] * (x / zs) + K[0, 1] * (y / zs) + K[0, 2], K[1, 1] * (y / zs) + K[1, 2], z


def _fixed_uv(points, K, T):
    from jaxdepth._src.geometry import camera_points, project_pixels
    p = camera_points(T, points)
    u, v, _, _ = project_pixels(p, K)
    return u, v, p[:, 2]


def _differences(form, points, Ks, Ts, *, height, width) -> list:
    """Per camera: points whose u / v / z bits, or rounded pixel, differ between the vmapped group and the call alone."""
    batched = jax.jit(jax.vmap(form, (None, 0, 0)))(points, Ks, Ts)
    alone = jax.jit(form)
    rows = []
    for c in range(Ks.shape[0]):
        one = [np.asarray(x) for x in alone(points, Ks[c], Ts[c])]
        many = [np.asarray(x[c]) for x in batched]
        front = (one[2] > 0.1) & (many[2] > 0.1)
        pix_one = (np.round(one[0]), np.round(one[1]))
        pix_many = (np.round(many[0]), np.round(many[1]))
        inside = lambda u, v: (u >= 0) & (u <= width - 1) & (v >= 0) & (v <= height - 1)  # noqa: E731
        moved = front & ((pix_one[0] != pix_many[0]) | (pix_one[1] != pix_many[1]))
        rows.append({"u_bits": int((one[0] != many[0])[front].sum()), "v_bits": int((one[1] != many[1])[front].sum()),
                     "z_bits": int((one[2] != many[2]).sum()), "other_pixel": int(moved.sum()),
                     "other_pixel_in_image": int((moved & (inside(*pix_one) | inside(*pix_many))).sum())})
    return rows


def _old_project_with_normals(points, valid, normals, T, K, *, height, width):
    """``pipeline.project_with_normals`` as it was before the fix (per-pixel transform of the winner)."""
    from jaxdepth._src.geometry import pixel_zbuffer, transform_points
    u, v, z = _plain_uv(points, K, T)
    depth, index = pixel_zbuffer(u, v, z, valid & (z > 0.1), height=height, width=width)
    hit = index >= 0
    safe = jnp.where(hit, index, 0).reshape(-1)
    points_cam = jnp.where(hit[None], transform_points(T, points[safe]).T.reshape(3, height, width), 0.0)
    normals_cam = jnp.where(hit[None], (T[:3, :3] @ normals[safe].T).reshape(3, height, width), 0.0)
    return depth, index, points_cam, normals_cam


def _timed(fn) -> float:
    t = time.perf_counter()
    jax.block_until_ready(fn())
    return time.perf_counter() - t


def _speed(points, valid, normals, Ks, Ts, *, height, width, rounds: int) -> dict:
    from jaxdepth._src.pipeline import project_with_normals
    forms = {"plain (before)": _old_project_with_normals, "fixed (now)": project_with_normals}
    fns = {}
    for name, form in forms.items():
        run = jax.jit(jax.vmap(lambda K, T, form=form: form(points, valid, normals, T, K, height=height, width=width)))
        fns[name] = lambda run=run: run(Ks, Ts)
    first = {name: _timed(fn) for name, fn in fns.items()}
    runs = {name: [] for name in fns}
    for _ in range(rounds):
        for name, fn in fns.items():
            runs[name].append(_timed(fn))
    ratio = [f / p for f, p in zip(runs["fixed (now)"], runs["plain (before)"])]
    return {"first_call_s": first, "median_s": {k: statistics.median(v) for k, v in runs.items()}, "runs_s": runs,
            "ratio_fixed_to_plain": statistics.median(ratio), "ratio_per_round": ratio}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--json", default=str(RESULTS / "projection_rounding.json"))
    args = ap.parse_args(argv)
    t0 = time.time()
    from jaxdepth.batch.sources_job import cloud_sources
    from jaxdepth.io import av2

    log = av2.read_log(LOG)
    rig = av2.read_rig(log)
    sources, _ = cloud_sources(av2.read_cloud(log), fallback=rig.lidar)
    cams = [c.as_camera() for c in rig.cameras]
    landscape = [c for c in cams if (c.height, c.width) == (1550, 2048)]
    Ks = jnp.stack([c.K for c in landscape]).astype(jnp.float32)
    Ts = jnp.stack([c.T_cam_lidar for c in landscape]).astype(jnp.float32)
    valid = jnp.asarray(sources.valid).reshape(-1)
    points = jnp.where(valid[:, None], jnp.asarray(sources.points, jnp.float32).reshape(-1, 3), 0.0)
    normals = points / (jnp.linalg.norm(points, axis=1, keepdims=True) + 1.0)   # any unit-ish vectors: timing only
    doc = {"what": "rig (vmapped) vs single-camera projection bits, plain float32 vs exact products; projection speed",
           "points": int(points.shape[0]), "cameras": [c.name for c in rig.cameras if (c.height, c.width) == (1550, 2048)],
           "xla_flags": os.environ.get("XLA_FLAGS", "")}
    for name, form in (("plain", _plain_uv), ("fixed", _fixed_uv)):
        doc[f"differences_{name}_6_cameras"] = _differences(form, points, Ks, Ts, height=1550, width=2048)
        doc[f"differences_{name}_2_cameras"] = _differences(form, points, Ks[:2], Ts[:2], height=1550, width=2048)
        print(name, doc[f"differences_{name}_6_cameras"], flush=True)
    doc["speed_projection_6_cameras"] = _speed(points, valid, normals, Ks, Ts, height=1550, width=2048,
                                               rounds=args.rounds)
    print(doc["speed_projection_6_cameras"]["median_s"], doc["speed_projection_6_cameras"]["ratio_fixed_to_plain"])
    write_results(args.json, doc, None, t0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
