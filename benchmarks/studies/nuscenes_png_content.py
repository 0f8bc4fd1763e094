"""Why the nuScenes job's PNG writes cost more CPU for the SGM's depth than for the nearest fill's (issue 38).

    python -m benchmarks.studies.nuscenes_png_content [--rounds 15] [--json PATH]

One sample of ``bench_nuscenes_job``'s dataroot (the shared sweep, six cameras at 1600 x 900) run through the
job with the default method and with ``--method nearest``; each of the twelve PNGs read back (uint16) and then,
in one process, interleaved rounds, medians of the thread CPU (``time.thread_time``): the whole
``encode_depth_png`` at the job's level, its zlib stream alone on the filtered rows (the library's encoder:
ISA-L with the extra ``fast-png``), and the float -> uint16 conversion (``encode_depth_uint16``). The content:
empty pixels, distinct values, the share of zero bytes in the "Up"-filtered rows (what the compressor sees), and
the compressed size. Writes benchmarks/results/nuscenes_png_content.json.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import pathlib
import time

import numpy as np

from benchmarks._common import RESULTS, write_results


def _thread_cpu(fn, rounds: int) -> list:
    out = []
    for _ in range(rounds):
        start = time.thread_time()
        fn()
        out.append(time.thread_time() - start)
    return out


def _up_filtered(depth_u16: np.ndarray) -> np.ndarray:
    """The rows as the encoder filters them ("Up": big-endian bytes minus the row above's, mod 256)."""
    rows = depth_u16.astype(">u2").view(np.uint8).reshape(depth_u16.shape[0], -1)
    up = rows.copy()
    up[1:] -= rows[:-1]
    return up


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=15)
    parser.add_argument("--json", type=pathlib.Path, default=RESULTS / "nuscenes_png_content.json")
    args = parser.parse_args(argv)
    t0 = time.time()

    from benchmarks.bench_nuscenes_job import build_dataroot, run_once
    from jaxdepth.io import depth_png

    level = depth_png.DEFAULT_PNG_COMPRESSION
    record = {"encoder": depth_png.png_encoder(), "level": level, "rounds": args.rounds, "methods": {}}
    with tempfile.TemporaryDirectory() as tmp:
        root = pathlib.Path(tmp) / "root"
        root.mkdir()
        build_dataroot(root, 1, 1)
        images = {}
        for method in ("sgm", "nearest"):
            out = pathlib.Path(tmp) / method
            run_once(root, out, method=method, sweeps=1, samples=1)
            images[method] = {p.stem: np.rint(depth_png.read_depth_png(p) * 256).astype(np.uint16)
                              for p in sorted(out.rglob("*.png"))}
    times = {(m, c, part): [] for m in images for c in images[m] for part in ("png", "zlib", "uint16")}
    filtered = {(m, c): _up_filtered(u16) for m in images for c, u16 in images[m].items()}
    for _ in range(args.rounds):             # interleaved: every image and part once a round
        for m in images:
            for c, u16 in images[m].items():
                metres = u16.astype(np.float32) / np.float32(256)
                framed = np.concatenate([np.full((u16.shape[0], 1), 2, np.uint8), filtered[m, c]], axis=1)
                times[m, c, "png"] += _thread_cpu(lambda: depth_png.encode_depth_png(u16, compression=level), 1)
                times[m, c, "zlib"] += _thread_cpu(lambda: depth_png._compress(framed, level), 1)
                times[m, c, "uint16"] += _thread_cpu(lambda: depth_png.encode_depth_uint16(metres), 1)
    for m in images:
        cams = {}
        for c, u16 in images[m].items():
            up = filtered[m, c]
            cams[c] = {"empty_share": float(np.mean(u16 == 0)), "distinct_values": int(np.unique(u16).size),
                       "up_zero_byte_share": float(np.mean(up == 0)),
                       "png_bytes": len(depth_png.encode_depth_png(u16, compression=level)),
                       **{f"{part}_cpu_ms": 1e3 * statistics.median(times[m, c, part])
                          for part in ("png", "zlib", "uint16")}}
        total = {k: sum(v[k] for v in cams.values()) for k in ("png_cpu_ms", "zlib_cpu_ms", "uint16_cpu_ms",
                                                                 "png_bytes")}
        record["methods"][m] = {"cameras": cams, "sample": total,
                                "mean_up_zero_byte_share": float(np.mean([v["up_zero_byte_share"]
                                                                          for v in cams.values()]))}
        print(m, {k: round(v, 2) for k, v in total.items()}, "Up-filtered zero bytes",
              round(record["methods"][m]["mean_up_zero_byte_share"], 3))
    s, n = record["methods"]["sgm"]["sample"], record["methods"]["nearest"]["sample"]
    record["sgm_over_nearest"] = {k: s[k] / n[k] for k in s}
    print("sgm / nearest", {k: round(v, 2) for k, v in record["sgm_over_nearest"].items()})
    with open("/proc/loadavg") as f:
        record["load_average"] = [float(x) for x in f.read().split()[:3]]
    write_results(args.json, {"command": "python -m benchmarks.studies.nuscenes_png_content " + " ".join(
        sys.argv[1:] if argv is None else argv), **record}, None, t0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
