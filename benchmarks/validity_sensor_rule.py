"""Validity from the sensor: the share of pixels --validity marks invalid on the shared nuScenes sample
(6 cameras, HDL-32E) and KITTI frame (HDL-64E), under the old fixed 16 px limit and the sensor rule
(3 scan-line spacings, jaxdepth._src.validity.sensor_max_seed_distance_px), and the share of invalid
pixels that are within one scan-line spacing of a LiDAR pixel (the rule must leave none).

Run: python -m benchmarks.validity_sensor_rule [--write-images]
Writes benchmarks/results/validity_sensor_rule.json (one row per camera and rule); with --write-images also
docs/images/validity_nuscenes.png and validity_kitti.png (the CAM_FRONT / camera 2 masks, 2x downscaled).
"""

from __future__ import annotations

import pathlib
import sys

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
ROWS: list = []
DATA = ROOT.parent / "shared" / "data"
if not DATA.exists():
    DATA = pathlib.Path("/work/shared/data")


def _rows(name, stages, cameras, lidar, metric, names):
    from jaxdepth._src import validity as vd
    out = []
    masks = {}
    spacing = np.asarray([float(vd.scan_line_spacing_px(cameras.K[i], lidar)) for i in range(len(names))])
    for label, limit in (("fixed 16 px", 16.0), ("sensor rule", None)):
        valid, dist = (np.asarray(a) for a in vd.rig_validity_and_distance(
            stages, cameras, lidar=lidar, metric=metric, max_seed_distance_px=limit))
        for i, cam in enumerate(names):
            inside = np.asarray(vd.fov_mask(cameras.K[i], cameras.T_cam_lidar[i], height=valid.shape[1],
                                            width=valid.shape[2], lidar=lidar))
            invalid = ~valid[i]
            near = invalid & inside & (dist[i] <= spacing[i])
            near_all = invalid & (dist[i] <= spacing[i])
            out.append(f"{name:8s} {cam:16s} {label:12s} spacing {spacing[i]:5.1f} px  invalid {100 * invalid.mean():5.1f} %"
                       f"  (inside the vertical FOV: {100 * (invalid & inside).sum() / max(inside.sum(), 1):5.1f} %)"
                       f"  invalid within one spacing of a LiDAR pixel: {int(near.sum())} px inside the FOV, "
                       f"{int(near_all.sum())} px in all (rows beyond the top / bottom beam)")
            masks[(label, cam)] = valid[i]
            ROWS.append({"data": name, "camera": cam, "rule": label, "spacing_px": round(float(spacing[i]), 3),
                         "invalid_share": round(float(invalid.mean()), 5),
                         "invalid_share_inside_fov": round(float((invalid & inside).sum() / max(inside.sum(), 1)), 5),
                         "invalid_within_one_spacing_inside_fov_px": int(near.sum()),
                         "invalid_within_one_spacing_px": int(near_all.sum())})
    return out, masks


def nuscenes():
    import jaxdepth
    from jaxdepth.io import pad_points, read_points
    from jaxdepth.io.rig import rig_from_nuscenes_calibration
    sample = DATA / "nuscenes" / "sample"
    rig = rig_from_nuscenes_calibration(sample / "calibration.json")
    points, _ = read_points(next(sample.glob("*.pcd.bin")), columns=5)
    padded, valid = pad_points(points)
    cameras = jaxdepth.stack_cameras([c.as_camera() for c in rig.cameras])
    stages = jaxdepth.complete_rig_stages(padded, valid, cameras, lidar=rig.lidar)
    return _rows("nuScenes", stages, cameras, rig.lidar, "l1", [c.name for c in rig.cameras])


def kitti():
    import jaxdepth
    from jaxdepth.io import pad_points, read_points
    from jaxdepth.io.rig import rig_from_kitti_raw
    frame = DATA / "kitti" / "drive_0001_frame05"
    rig = rig_from_kitti_raw(frame / "calib_cam_to_cam.txt", frame / "calib_velo_to_cam.txt", cameras=(2,))
    points, _ = read_points(frame / "lidar_data.bin", columns=4)
    padded, valid = pad_points(points)
    cameras = jaxdepth.stack_cameras([c.as_camera() for c in rig.cameras])
    stages = jaxdepth.complete_rig_stages(padded, valid, cameras, lidar=rig.lidar)
    return _rows("KITTI", stages, cameras, rig.lidar, "l1", [c.name for c in rig.cameras])


def main(argv):
    import cv2
    lines_n, masks_n = nuscenes()
    lines_k, masks_k = kitti()
    for line in lines_n + lines_k:
        print(line)
    import json
    out = ROOT / "benchmarks" / "results" / "validity_sensor_rule.json"
    out.write_text(json.dumps({"factor": 3.0, "metric": "l1", "rows": ROWS}, indent=2) + "\n")
    print(f"wrote {out}")
    if "--write-images" in argv:
        for path, mask in ((ROOT / "docs/images/validity_nuscenes.png", masks_n[("sensor rule", "CAM_FRONT")]),
                           (ROOT / "docs/images/validity_kitti.png", next(v for (rule, _), v in masks_k.items()
                                                                          if rule == "sensor rule"))):
            img = np.where(mask, 255, 0).astype(np.uint8)
            img = cv2.resize(img, (img.shape[1] // 2, img.shape[0] // 2), interpolation=cv2.INTER_AREA)
            cv2.imwrite(str(path), img, [cv2.IMWRITE_PNG_COMPRESSION, 9])
            print(f"wrote {path} ({path.stat().st_size // 1024} KB)")


if __name__ == "__main__":
    main(sys.argv[1:])
