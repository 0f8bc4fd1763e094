"""SHA-256 of every output array of the CLI and the API on the shared data: a bit-for-bit guard for refactors.

Runs, in one process:

* KITTI ``drive_0001_frame05`` camera 2, cropped to the 352x1216 benchmark window:
  ``jaxdepth complete`` on the single PNG with the default config, with ``--distance l2``,
  with ``--guidance-weight 50`` (image_02, cropped alike) and with ``--validity
  --seed-distance``; ``jaxdepth eval`` of the default output against the cropped ground
  truth; ``complete`` on a KITTI raw tree built from the frame (``--crop --camera 2``, the
  dataset-discovery path); the API's ``complete_stages`` (every stage) on the crop and
  ``complete_points_stages`` on the raw sweep (full-size camera 2).
* nuScenes ``sample``: ``jaxdepth complete-rig`` (rig JSON written from
  :func:`jaxdepth.io.rig_from_nuscenes_calibration`, with ``--validity --seed-distance``)
  and the API's ``complete_rig_stages``.
* the synthetic street scene: ``jaxdepth demo`` and the API's ``make_street_scene``
  (with images), ``complete_points_stages`` and ``complete_rig_stages``.
* the multi-source path on a synthetic drive (3 sweeps of one LiDAR, and of two): :func:`sweeps`.

Each output is hashed as decoded array bytes (dtype and shape included). Same code,
same hashes: a refactor that claims "no behaviour change" must leave the JSON unchanged.

    PYTHONPATH=$PWD python benchmarks/output_fingerprint.py [--json benchmarks/results/output_fingerprint.json]
        [--check benchmarks/results/output_fingerprint.json]   # exit 1 when any hash differs
        [--data ../shared/data]   # e.g. when run from an exported snapshot of a commit
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import io
import json
import pathlib
import shutil
import sys
import tempfile

import cv2
import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
FRAME = DATA / "kitti" / "drive_0001_frame05"
NUSCENES = DATA / "nuscenes" / "sample"


def use_data(root: pathlib.Path) -> None:
    global DATA, FRAME, NUSCENES
    DATA = root
    FRAME = DATA / "kitti" / "drive_0001_frame05"
    NUSCENES = DATA / "nuscenes" / "sample"
CROP_ROWS, CROP_COLS = slice(23, 375), slice(13, 1229)


def digest(array) -> str:
    a = np.ascontiguousarray(np.asarray(array))
    h = hashlib.sha256(f"{a.dtype.str}{a.shape}".encode())
    h.update(a.tobytes())
    return h.hexdigest()


def png_digest(path: pathlib.Path) -> str:
    return digest(cv2.imread(str(path), cv2.IMREAD_UNCHANGED))


def stages_digests(stages, prefix: str) -> dict:
    return {f"{prefix}.{name}": digest(value) for name, value in stages._asdict().items() if value is not None}


def run_cli(argv) -> None:
    from jaxdepth import cli
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = cli.main(list(map(str, argv)))
    if code != 0:
        raise SystemExit(f"jaxdepth {' '.join(map(str, argv))} exited {code}:\n{out.getvalue()}{err.getvalue()}")


def folder_digests(folder: pathlib.Path, prefix: str) -> dict:
    return {f"{prefix}/{p.relative_to(folder).as_posix()}": png_digest(p)
            for p in sorted(folder.rglob("*.png"))}


def kitti_crop_K() -> np.ndarray:
    from jaxdepth.io.calib import read_kitti_raw_calib
    calib = read_kitti_raw_calib(FRAME / "calib_cam_to_cam.txt", FRAME / "calib_velo_to_cam.txt")
    K = np.array(calib["cameras"][2]["K"], np.float64)
    K[0, 2] -= CROP_COLS.start
    K[1, 2] -= CROP_ROWS.start
    return K


def kitti(tmp: pathlib.Path) -> dict:
    import jaxdepth
    from jaxdepth._src import presets
    from jaxdepth.io.points import read_points

    out = {}
    sel = tmp / "kitti_sel"
    (sel / "images").mkdir(parents=True)
    sparse = cv2.imread(str(FRAME / "velodyne_raw_image_02.png"), cv2.IMREAD_UNCHANGED)[CROP_ROWS, CROP_COLS]
    image = cv2.imread(str(FRAME / "image_02.png"), cv2.IMREAD_UNCHANGED)[CROP_ROWS, CROP_COLS]
    truth = cv2.imread(str(FRAME / "groundtruth_image_02.png"), cv2.IMREAD_UNCHANGED)[CROP_ROWS, CROP_COLS]
    cv2.imwrite(str(sel / "frame.png"), sparse)
    cv2.imwrite(str(sel / "images" / "frame.png"), image)
    (sel / "gt").mkdir()
    cv2.imwrite(str(sel / "gt" / "frame.png"), truth)
    K = kitti_crop_K()
    (sel / "K.txt").write_text(" ".join(f"{v:.10g}" for v in K.ravel()))
    base = ["complete", sel / "frame.png"]
    opts = ["--intrinsics", sel / "K.txt", "--quiet", "--cpu-devices", "1"]
    runs = {"default": [], "l2": ["--distance", "l2"],
            "guided50": ["--guidance-weight", "50", "--image-dir", sel / "images"],
            "extras": ["--validity", "--seed-distance"]}
    for name, extra in runs.items():
        folder = tmp / f"kitti_cli_{name}"
        folder.mkdir()
        run_cli(base + [folder / "frame.png"] + opts + extra)
        out.update(folder_digests(folder, f"kitti.cli.{name}"))
    evaluation = tmp / "eval.json"
    pred = tmp / "kitti_cli_default"
    run_cli(["eval", pred, sel / "gt", "--json", evaluation])
    table = json.loads(evaluation.read_text())
    out["kitti.cli.eval.json"] = hashlib.sha256(
        json.dumps(table, sort_keys=True, default=str).replace(str(tmp), "TMP").encode()).hexdigest()

    raw = tmp / "kitti_raw" / "2011_09_26"
    drive = raw / "2011_09_26_drive_0001_sync"
    (drive / "velodyne_points" / "data").mkdir(parents=True)
    (drive / "image_02" / "data").mkdir(parents=True)
    shutil.copyfile(FRAME / "lidar_data.bin", drive / "velodyne_points" / "data" / "0000000005.bin")
    shutil.copyfile(FRAME / "image_02.png", drive / "image_02" / "data" / "0000000005.png")
    for calib in ("calib_cam_to_cam.txt", "calib_velo_to_cam.txt"):
        shutil.copyfile(FRAME / calib, raw / calib)
    dst = tmp / "kitti_raw_out"
    run_cli(["complete", raw, dst, "--crop", "--camera", "2", "--quiet", "--cpu-devices", "1"])
    out.update(folder_digests(dst, "kitti.cli.raw_tree"))

    stages = jaxdepth.complete_stages(sparse.astype(np.float32) / 256.0, K.astype(np.float32))
    out.update(stages_digests(stages, "kitti.api.complete_stages"))
    points, _ = read_points(FRAME / "lidar_data.bin", columns=4)
    padded, valid = jaxdepth_pad(points)
    full = cv2.imread(str(FRAME / "velodyne_raw_image_02.png"), cv2.IMREAD_UNCHANGED)
    camera = jaxdepth.Camera(K=np.asarray(presets.KITTI_K_CAM2, np.float32),
                             T_cam_lidar=np.asarray(presets.KITTI_T_CAM2_LIDAR, np.float32),
                             height=full.shape[0], width=full.shape[1])
    stages = jaxdepth.complete_points_stages(padded, valid, camera)
    out.update(stages_digests(stages, "kitti.api.complete_points_stages"))
    return out


def jaxdepth_pad(points):
    from jaxdepth.io import pad_points
    return pad_points(points)


def nuscenes(tmp: pathlib.Path) -> dict:
    import jaxdepth
    from jaxdepth.io import read_points, rig_from_nuscenes_calibration, write_rig_json

    out = {}
    rig = rig_from_nuscenes_calibration(NUSCENES / "calibration.json")
    write_rig_json(tmp / "rig.json", rig)
    sweep = next(NUSCENES.glob("*LIDAR_TOP*.pcd.bin"))
    dst = tmp / "nuscenes_rig"
    run_cli(["complete-rig", sweep, tmp / "rig.json", dst, "--quiet", "--validity", "--seed-distance"])
    out.update(folder_digests(dst, "nuscenes.cli.complete_rig"))
    points, _ = read_points(sweep, columns=5)
    padded, valid = jaxdepth_pad(points)
    cameras = jaxdepth.stack_cameras([camera.as_camera() for camera in rig.cameras])
    stages = jaxdepth.complete_rig_stages(padded, valid, cameras, lidar=rig.lidar)
    out.update(stages_digests(stages, "nuscenes.api.complete_rig_stages"))
    return out


def synthetic(tmp: pathlib.Path) -> dict:
    import jaxdepth

    out = {}
    dst = tmp / "demo"
    run_cli(["demo", "--out", dst])
    out.update(folder_digests(dst, "synthetic.cli.demo"))
    frame = jaxdepth.make_street_scene(0, cameras="stereo", images=True)
    out["synthetic.scene.points"] = digest(frame.points)
    out["synthetic.scene.valid"] = digest(frame.valid)
    for i, (dense, image) in enumerate(zip(frame.dense_depth, frame.images)):
        out[f"synthetic.scene.dense_depth[{i}]"] = digest(dense)
        out[f"synthetic.scene.image[{i}]"] = digest(image)
    stages = jaxdepth.complete_points_stages(frame.points, frame.valid, frame.cameras[0], lidar=frame.lidar)
    out.update(stages_digests(stages, "synthetic.api.complete_points_stages"))
    stages = jaxdepth.complete_points_stages(frame.points, frame.valid, frame.cameras[0], lidar=frame.lidar,
                                             image=frame.images[0],
                                             config=jaxdepth.SGMConfig(guidance_weight=50.0))
    out.update(stages_digests(stages, "synthetic.api.complete_points_stages_guided50"))
    cameras = jaxdepth.stack_cameras(frame.cameras)
    stages = jaxdepth.complete_rig_stages(frame.points, frame.valid, cameras, lidar=frame.lidar)
    out.update(stages_digests(stages, "synthetic.api.complete_rig_stages"))
    # cameras of two sizes on one canvas: each camera's stages use its own size, never the padding
    cropped = jaxdepth.Camera(K=crop_K(frame.cameras[1].K, top=52, left=300), T_cam_lidar=frame.cameras[1].T_cam_lidar,
                              height=300, width=600)
    cameras = jaxdepth.stack_cameras([frame.cameras[0], cropped])
    stages = jaxdepth.complete_rig_stages(frame.points, frame.valid, cameras, lidar=frame.lidar)
    out.update(stages_digests(stages, "synthetic.api.complete_rig_stages_mixed_sizes"))
    return out


def sweeps(tmp: pathlib.Path) -> dict:
    """The multi-source path (``complete_cloud``, as ``complete-rig`` with a sweeps JSON runs it) on the
    synthetic drive of :func:`jaxdepth._src.synthetic_sequences.make_street_sequence`: 3 sweeps of one
    LiDAR (rule 6 runs by default) and 3 sweeps of two LiDARs (it does not)."""
    from jaxdepth._src.synthetic_sequences import make_street_sequence
    from jaxdepth.batch.sources_job import complete_cloud
    from jaxdepth.io.rig import Rig, RigCamera
    from jaxdepth.io.sources import SourceCloud

    out = {}
    for lidars in (1, 2):
        sq = make_street_sequence(0, sweeps=3, lidars=lidars, image_scale=0.25)
        cloud = SourceCloud(points=sq.points, source=sq.source, T_ref_source=sq.T_ref_source, lidars=sq.lidars,
                            sweep=sq.sweep, names=sq.names)
        cam = sq.camera
        rig = Rig(lidar=sq.lidars[0], cameras=(RigCamera("cam", cam.width, cam.height, np.asarray(cam.K),
                                                         np.asarray(cam.T_cam_lidar)),))
        out.update(stages_digests(complete_cloud(cloud, rig, stages=True), f"drive.sweeps.{lidars}_lidars"))
    return out


def crop_K(K, *, top: int, left: int) -> np.ndarray:
    """Intrinsics of the image cropped at row ``top``, column ``left``."""
    K = np.array(K, np.float32)
    K[0, 2] -= left
    K[1, 2] -= top
    return K


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", type=pathlib.Path, default=None, help="write the hashes to this JSON file")
    parser.add_argument("--check", type=pathlib.Path, default=None, help="compare with this JSON; exit 1 on change")
    parser.add_argument("--data", type=pathlib.Path, default=DATA, help="the shared data folder (default ../shared/data)")
    args = parser.parse_args(argv)
    use_data(args.data.resolve())
    for path in (FRAME, NUSCENES):
        if not path.exists():
            raise SystemExit(f"{path}: shared data not found")
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = pathlib.Path(tmp_name)
        hashes = {}
        for part in (kitti, nuscenes, synthetic, sweeps):
            hashes.update(part(tmp))
    hashes = dict(sorted(hashes.items()))
    for name, value in hashes.items():
        print(f"{value[:16]}  {name}")
    if args.json:
        args.json.write_text(json.dumps(hashes, indent=1) + "\n")
    if args.check:
        want = json.loads(args.check.read_text())
        changed = sorted(k for k in set(want) | set(hashes) if want.get(k) != hashes.get(k))
        for name in changed:
            print(f"CHANGED {name}: {want.get(name, '-')[:16]} -> {hashes.get(name, '-')[:16]}")
        print(f"{len(hashes)} outputs, {len(changed)} changed")
        return 1 if changed else 0
    print(f"{len(hashes)} outputs")
    return 0


if __name__ == "__main__":
    sys.exit(main())
