"""Step 4's Gaussian sigma on the KITTI ground truth and the twins (issue 37, sigma2; nothing here sets a default).

Merges runs of ``benchmarks.accuracy_kitti --smoothing-sigma S`` and ``benchmarks.accuracy_twins
--smoothing-sigma S`` (one JSON per sigma, or per sigma and set of rigs) into one result and prints the docs'
table: RMSE / MAE (mm) of the final SGM per set and sigma, the city-block fill beside the twins, and each
sigma's change against the first one given.

    python -m benchmarks.studies.smoothing_sigma --kitti K14.json K17.json K20.json \\
        --twins T14.json T20.json T20_AV2.json --json benchmarks/results/smoothing_sigma_sigma2.json
"""

from __future__ import annotations

import argparse
import json
import pathlib


def _load(paths: list) -> list:
    return [json.loads(pathlib.Path(p).read_text()) for p in paths]


def merge(kitti: list, twins: list) -> dict:
    """``{"kitti": {sigma: {rmse, mae, irmse, imae}}, "twins": {sigma: {"rig, scale s": {sweeps: {sgm, nearest}}}}}``."""
    out = {"kitti": {}, "twins": {}, "twin_settings": {}}
    for d in kitti:
        out["kitti"][f"{d['config']['smoothing_sigma_px']:g}"] = d["mean"]["with_outlier_removal"]
    for d in twins:
        sigma = f"{d['settings']['smoothing_sigma_px']:g}"
        per = out["twins"].setdefault(sigma, {})
        for rig, rows in d["summary"].items():
            key = f"{rig}, scale {d['settings']['scales'][rig]:g}"     # a twin at two scales: two rows
            for n, row in rows.items():
                per.setdefault(key, {})[n] = {m: row[m] for m in ("sgm", "nearest")}
        out["twin_settings"].setdefault(sigma, []).append(
            {k: d["settings"][k] for k in ("rigs", "sweeps", "seeds", "scales", "camera_sizes")})
    return out


def table(doc: dict) -> str:
    sigmas = sorted(doc["kitti"] | doc["twins"], key=float)
    ref = sigmas[0]

    def cell(v, r):
        if v is None:
            return "-"
        if r is None or v is r:
            return f"{v['rmse']:.1f} / {v['mae']:.1f}"
        return (f"{v['rmse']:.1f} / {v['mae']:.1f} ({100 * (v['rmse'] / r['rmse'] - 1):+.1f} / "
                f"{100 * (v['mae'] / r['mae'] - 1):+.1f} %)")

    lines = ["| set | " + " | ".join(f"sigma {s}" for s in sigmas) + " | city block |",
             "|---|" + "---|" * (len(sigmas) + 1)]
    k = doc["kitti"]
    lines.append("| KITTI ground truth (2 frames) | " + " | ".join(cell(k.get(s), k.get(ref)) for s in sigmas) + " | - |")
    rigs = list(dict.fromkeys(r for per in doc["twins"].values() for r in per))
    for rig in rigs:
        for n in sorted({n for per in doc["twins"].values() for n in per.get(rig, {})}, key=int):
            rows = [doc["twins"].get(s, {}).get(rig, {}).get(n) for s in sigmas]
            r = rows[0]["sgm"] if rows[0] else None
            fill = next((x["nearest"] for x in rows if x), None)
            lines.append(f"| twin {rig}, {n} sweep{'s' if n != '1' else ''} | "
                         + " | ".join(cell(x["sgm"] if x else None, r) for x in rows) + f" | {cell(fill, None)} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--kitti", nargs="+", default=[], help="accuracy_kitti JSONs, one per sigma")
    parser.add_argument("--twins", nargs="+", default=[], help="accuracy_twins JSONs (any rigs, one sigma each)")
    parser.add_argument("--json", help="write the merged result here")
    parser.add_argument("--table", metavar="JSON", help="print the table of a merged result and exit")
    args = parser.parse_args(argv)
    doc = json.loads(pathlib.Path(args.table).read_text()) if args.table else merge(_load(args.kitti), _load(args.twins))
    print(table(doc))
    if args.json and not args.table:
        pathlib.Path(args.json).write_text(json.dumps(doc, indent=2, sort_keys=True))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
