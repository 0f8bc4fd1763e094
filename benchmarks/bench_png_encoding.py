"""The depth PNGs' encoding on real outputs: CPU and bytes of row filters, zlib levels and strategies.

The jobs' own outputs, default (``sgm``) and ``--method nearest``: the Argoverse 2 job on the shared
two-sweep log (14 PNGs per method, 2048 x 1550 and one 1550 x 2048), the nuScenes job on the shared sample
(6 cameras, 1600 x 900; :func:`benchmarks.bench_nuscenes_job.build_dataroot`, one sample) and the KITTI frame
(camera 2, 352 x 1216 crop; :func:`jaxdepth.complete_with`), written by the code in use into ``--outputs``
(kept: a second run reuses them; ``--regenerate`` writes them again). Each PNG is decoded (OpenCV) to its
uint16 array; every variant encodes every array on one thread, ``--rounds`` rounds in an order rotated per
round, and reports per set the median over rounds of the summed thread CPU (``time.thread_time``) and the bytes.
Each variant's bytes are decoded again by OpenCV (libpng) and Pillow (its own PNG decoder; where installed)
and compared with the array (a variant that does not round-trip aborts the run).

Variants: the row filter (``up``, ``sub``, ``avg``, ``paeth``, ``none``, all computed in NumPy on the
big-endian bytes as PNG defines them, one filter for every row) x zlib level x strategy
(``zlib.compressobj(level, DEFLATED, 15, memLevel, strategy)``: default, ``Z_FILTERED``, ``Z_RLE``,
``Z_HUFFMAN_ONLY``; memLevel 8 unless ``--mem-levels`` adds others, a ``-mem9`` suffix); or, as a
"strategy" named ``isal`` or ``libdeflate``, another library's zlib stream at that level (ISA-L through the
``isal`` package, libdeflate through ``deflate``: not dependencies of jaxdepth; put them on ``PYTHONPATH``,
e.g. ``pip install --target DIR isal deflate``). ``up-1-default`` is
the encoding of main 937654c (``encode_depth_png``: ``zlib.compress`` at level 1, memLevel 8), byte for byte
(and of ``encode_depth_png`` without the extra ``fast-png``; with it, ``up-1-isal`` is, branch pngisal).

    python -m benchmarks.bench_png_encoding [--outputs /tmp/pngfast] [--rounds 5] [--json PATH]
"""

from __future__ import annotations

import argparse
import io
import pathlib
import statistics
import struct
import sys
import time
import zlib

import numpy as np

from benchmarks._common import RESULTS, write_results

STRATEGIES = {"default": zlib.Z_DEFAULT_STRATEGY, "filtered": zlib.Z_FILTERED, "rle": zlib.Z_RLE,
              "huffman": zlib.Z_HUFFMAN_ONLY}
AV2_LOG = "7fab2350-7eaf-3b7e-a39d-6937a4c1bede"


def _isal(rows, level):
    from isal import isal_zlib                   # python-isal (ISA-L), levels 0-3; not a dependency
    return isal_zlib.compress(rows, level)


def _libdeflate(rows, level):
    import deflate                               # libdeflate's wrapper, levels 1-12; not a dependency
    return deflate.zlib_compress(rows, level)


#: ``--strategies`` names that are zlib-compatible libraries instead of a zlib strategy (installed by hand).
LIBRARIES = {"isal": _isal, "libdeflate": _libdeflate}


def generate(out: pathlib.Path) -> None:
    """The jobs' PNGs of both methods under ``out/<set>_<method>/``."""
    import tempfile

    from benchmarks._common import DATA, load_frame
    from benchmarks.bench_nuscenes_job import VERSION, build_dataroot
    from jaxdepth.batch.av2_job import run_av2
    from jaxdepth.batch.nuscenes_job import run_nuscenes
    from jaxdepth.io.depth_png import write_depth_png

    sparse, K, T, _ = load_frame()
    import jaxdepth
    with tempfile.TemporaryDirectory() as tmp:
        build_dataroot(pathlib.Path(tmp) / "nusc", 1, 1)
        for method in ("sgm", "nearest"):
            kitti = out / f"kitti_{method}"
            kitti.mkdir(parents=True, exist_ok=True)
            write_depth_png(kitti / "image_02.png", np.asarray(jaxdepth.complete_with(sparse, K, T, method=method)))
            summary = run_nuscenes(pathlib.Path(tmp) / "nusc", out / f"nuscenes_{method}", version=VERSION,
                                   sweeps=1, method=method)
            assert not summary.failed, summary.failed
            summary = run_av2(DATA / "av2" / "sensor" / "val" / AV2_LOG, out / f"av2_{method}", method=method)
            assert not summary.failed, summary.failed


def filter_rows(big_endian: np.ndarray, kind: str) -> np.ndarray:
    """(H, 2W) big-endian bytes -> (H, 2W + 1) PNG rows: the filter type byte, then the filtered bytes
    (16-bit greyscale: 2 bytes per pixel, so "left" is 2 bytes back; modulo 256)."""
    h, n = big_endian.shape
    rows = np.empty((h, n + 1), np.uint8)
    x = big_endian
    if kind == "none":
        rows[:, 0] = 0
        rows[:, 1:] = x
        return rows
    if kind == "up":
        rows[:, 0] = 2
        rows[0, 1:] = x[0]
        np.subtract(x[1:], x[:-1], out=rows[1:, 1:])
        return rows
    if kind == "sub":
        rows[:, 0] = 1
        rows[:, 1:3] = x[:, :2]
        np.subtract(x[:, 2:], x[:, :-2], out=rows[:, 3:])
        return rows
    left = np.zeros_like(x, np.int16)
    left[:, 2:] = x[:, :-2]
    up = np.zeros_like(x, np.int16)
    up[1:] = x[:-1]
    if kind == "avg":
        rows[:, 0] = 3
        pred = (left + up) >> 1
    elif kind == "paeth":
        rows[:, 0] = 4
        upleft = np.zeros_like(x, np.int16)
        upleft[1:, 2:] = x[:-1, :-2]
        p = left + up - upleft
        pa, pb, pc = np.abs(p - left), np.abs(p - up), np.abs(p - upleft)
        pred = np.where((pa <= pb) & (pa <= pc), left, np.where(pb <= pc, up, upleft))
    else:
        raise ValueError(kind)
    np.subtract(x, pred.astype(np.uint8), out=rows[:, 1:], casting="unsafe")
    return rows


def _chunk(tag: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(data, zlib.crc32(tag)))


def encode(array: np.ndarray, kind: str, level: int, strategy: str, mem_level: int = 8) -> bytes:
    h, w = array.shape
    rows = filter_rows(array.astype(">u2").view(np.uint8).reshape(h, 2 * w), kind)
    if strategy in LIBRARIES:                     # another library's zlib stream at its own level
        idat = LIBRARIES[strategy](rows, level)
    elif strategy == "default" and mem_level == 8:  # the library's call (level 0's stored blocks differ otherwise)
        idat = zlib.compress(rows, level)
    else:
        z = zlib.compressobj(level, zlib.DEFLATED, 15, mem_level, STRATEGIES[strategy])
        idat = z.compress(rows) + z.flush()
    return (b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 16, 0, 0, 0, 0))
            + _chunk(b"IDAT", idat) + _chunk(b"IEND", b""))


def variants(filters, levels, strategies, mem_levels) -> list[tuple]:
    out = []
    for kind in filters:
        for level in levels:
            for strategy in strategies:
                for mem in mem_levels:
                    if level == 0 and (strategy not in ("default", *LIBRARIES) or mem != mem_levels[0]):
                        continue                  # zlib's level 0 stores: no strategy or memory level applies
                    if strategy in LIBRARIES and (mem != mem_levels[0] or strategy == "libdeflate" and level == 0):
                        continue
                    out.append((kind, level, strategy, mem))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--outputs", type=pathlib.Path, default=pathlib.Path("/tmp/pngfast_outputs"))
    ap.add_argument("--regenerate", action="store_true")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--filters", default="up,sub,avg,paeth,none")
    ap.add_argument("--levels", default="0,1,2")
    ap.add_argument("--strategies", default="default,filtered,rle,huffman",
                    help="zlib strategies, and the libraries 'isal' / 'libdeflate' (comma-separated)")
    ap.add_argument("--mem-levels", default="8", help="zlib memLevel (8: zlib.compress's, main's bytes)")
    ap.add_argument("--json", type=pathlib.Path, default=RESULTS / "png_encoding.json")
    args = ap.parse_args(argv)
    import cv2
    try:
        from PIL import Image as pil             # a second decoder where installed (matplotlib brings it)
    except ImportError:
        pil = None

    t0 = time.perf_counter()
    if args.regenerate or not any(args.outputs.glob("*_sgm")):
        generate(args.outputs)
    sets = {}
    for folder in sorted(p for p in args.outputs.iterdir() if p.is_dir()):
        files = sorted(folder.rglob("*.png"))
        sets[folder.name] = [cv2.imread(str(f), cv2.IMREAD_UNCHANGED) for f in files]
        assert all(a.dtype == np.uint16 for a in sets[folder.name])
    names = variants(args.filters.split(","), [int(v) for v in args.levels.split(",")], args.strategies.split(","),
                     [int(v) for v in args.mem_levels.split(",")])
    cpu = {(v, s): [] for v in names for s in sets}
    size = {}
    for v in names:                             # each variant's bytes once: sizes and the round trip
        for s, arrays in sets.items():
            blobs = [encode(a, *v) for a in arrays]
            for a, b in zip(arrays, blobs):
                back = cv2.imdecode(np.frombuffer(b, np.uint8), cv2.IMREAD_UNCHANGED)
                if back is None or back.dtype != np.uint16 or not np.array_equal(back, a):
                    raise SystemExit(f"{v} on {s}: OpenCV decodes other values")
                if pil is not None and not np.array_equal(np.asarray(pil.open(io.BytesIO(b))), a):
                    raise SystemExit(f"{v} on {s}: Pillow decodes other values")
            size[v, s] = sum(len(b) for b in blobs)
    for r in range(args.rounds):
        shift = r % len(names)
        for v in names[shift:] + names[:shift]:
            for s, arrays in sets.items():
                start = time.thread_time()
                for a in arrays:
                    encode(a, *v)
                cpu[v, s].append(time.thread_time() - start)
        print(f"round {r} done, load {open('/proc/loadavg').read().split()[0]}", flush=True)
    rows = []
    for v in names:
        row = {"variant": "-".join(map(str, v[:3])) + ("" if v[3] == 8 else f"-mem{v[3]}"), "filter": v[0],
               "level": v[1], "strategy": v[2], "mem_level": v[3]}
        for s in sets:
            row[s] = {"files": len(sets[s]), "cpu_s": statistics.median(cpu[v, s]), "rounds_cpu_s": cpu[v, s],
                      "bytes": size[v, s]}
        rows.append(row)
    ref = next(r for r in rows if r["variant"] == "up-1-default")
    print("variant".ljust(22) + "".join(f"{s:>26}" for s in sets))
    for row in rows:
        print(row["variant"].ljust(22) + "".join(
            f"{row[s]['cpu_s'] * 1e3:8.1f} ms {row[s]['bytes'] / 1e6:6.2f} MB "
            f"{row[s]['cpu_s'] / ref[s]['cpu_s']:4.2f}x" for s in sets))
    doc = {"sets": {s: {"files": len(a), "shapes": sorted({str(x.shape) for x in a})} for s, a in sets.items()},
           "rounds": args.rounds, "variants": rows,
           "load_average_end": open("/proc/loadavg").read().split()[:3]}
    write_results(args.json, doc, None, t0)
    print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
