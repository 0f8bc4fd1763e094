"""The README stays short, its links and result files exist, its figures match them, its API block runs."""

from __future__ import annotations

import json
import os
import pathlib
import re

import numpy as np
import pytest

REPO = pathlib.Path(__file__).resolve().parent.parent
README = REPO / "README.md"
PAGES = [README, REPO / "benchmarks" / "README.md", *sorted((REPO / "docs").glob("*.md"))]
LINK = re.compile(r"(?<!!)\[[^\]]*\]\(([^)\s]+)\)")


def _slug(heading: str) -> str:
    """GitHub's anchor of a Markdown heading."""
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower().replace("`", ""))
    return text.replace(" ", "-")


def _anchors(page: pathlib.Path) -> set[str]:
    text = re.sub(r"```.*?```", "", page.read_text(), flags=re.S)
    return {_slug(m) for m in re.findall(r"^#+ (.+)$", text, flags=re.M)}


def test_readme_is_short():
    assert len(README.read_text().splitlines()) <= 250


def test_readme_starts_with_the_two_fresh_machine_commands():
    lines = README.read_text().splitlines()
    block = lines[lines.index("```bash"):lines.index("```bash") + 7]
    assert "jaxdepth demo" in block[2] and "pip install -e ." in block[2]
    assert "python -m pytest" in block[5] and 'pip install -e ".[test' in block[5]


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(REPO)))
def test_relative_links_point_to_existing_files_and_headings(page):
    assert page.exists(), page
    broken = []
    for target in LINK.findall(page.read_text()):
        if re.match(r"^[a-z]+:", target):  # http:, https:, mailto:
            continue
        path, _, anchor = target.partition("#")
        file = (page.parent / path).resolve() if path else page
        if not file.exists():
            broken.append(f"{target}: no file {file}")
        elif anchor and file.suffix == ".md" and anchor not in _anchors(file):
            broken.append(f"{target}: no heading #{anchor} in {file.relative_to(REPO)}")
    assert not broken, broken


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(REPO)))
def test_named_result_files_exist(page):
    named = set(re.findall(r"(?<![\w/])(?:benchmarks/)?results/[\w.\-]+\.json", page.read_text()))
    missing = sorted(n for n in named if not (REPO / "benchmarks" / n.removeprefix("benchmarks/")).exists())
    assert not missing, missing


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(REPO)))
def test_named_benchmark_scripts_exist(page):
    text = page.read_text()
    named = {f"{m}.py" for m in re.findall(r"\bbenchmarks/[\w/]+(?=\.py)", text)}
    named |= {m.replace(".", "/") + ".py" for m in re.findall(r"python -m (benchmarks(?:\.\w+)+)(?=[\s`\]])", text)}
    missing = sorted(n for n in named if not (REPO / n).exists())
    assert not missing, missing


def test_readme_accuracy_table_is_the_json():
    """Every row of the README's accuracy table equals its row in accuracy_rigs.json (0.1 mm)."""
    assert "benchmarks/results/accuracy_rigs.json" in README.read_text()
    rows = _results("accuracy_rigs.json")["rows"]
    methods = ("sgm", "sgm_no_removal", "nearest", "nearest_l2", "ip_basic")
    checked = 0
    for cells in _table("| set | SGM |"):
        assert cells[0] in rows, f"README row {cells[0]!r} is not in accuracy_rigs.json"
        scores = rows[cells[0]]["scores"]
        for cell, method in zip(cells[1:], methods):
            rmse, mae = (float(x) for x in cell.split("/"))
            assert (rmse, mae) == (round(scores[method]["rmse"], 1), round(scores[method]["mae"], 1)), (cells[0], method)
        checked += 1
    assert checked >= 4


def _results(name: str) -> dict:
    return json.loads((REPO / "benchmarks" / "results" / name).read_text())


def _table(header: str) -> list[list[str]]:
    """The body rows of the README table whose header row starts with ``header``, as stripped cells."""
    lines = README.read_text().splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith(header))
    rows = []
    for line in lines[start + 2:]:
        if not line.startswith("|"):
            break
        rows.append([c.strip().replace("*", "") for c in line.strip().strip("|").split("|")])
    return rows


#: Header of every README table -> what checks it (a new table needs a check, or a reason here).
README_TABLES = {
    "| flag | file | content |": "no figures: the extra outputs (tests/test_extras_cli.py runs each flag)",
    "| set | SGM |": "test_readme_accuracy_table_is_the_json",
    "| hold-out | SGM, per source |": "test_readme_av2_table_is_the_json",
    "| what | jaxdepth | IP_Basic (OpenCV) |": "test_readme_speed_table_is_the_json",
}


def test_every_readme_table_is_known():
    headers = [line for line in README.read_text().splitlines()
               if line.startswith("| ") and not line.startswith("|---")]
    other_lines = [h for h in headers if not any(h.startswith(k) for k in README_TABLES)]
    tables = [k for k in README_TABLES if any(h.startswith(k) for h in headers)]
    assert sorted(tables) == sorted(README_TABLES), "a table the README no longer has"
    bodies = sum(len(_table(k)) for k in README_TABLES)
    assert len(other_lines) == bodies, "a README table that no test checks against its JSON"


def test_readme_av2_table_is_the_json():
    """Both rows of the Argoverse 2 table equal accuracy_av2.json's means (0.1 mm)."""
    protocols = _results("accuracy_av2.json")["protocols"]
    methods = ("sgm_sources", "sgm_single_origin", "nearest", "nearest_l2", "ip_basic")
    rows = _table("| hold-out | SGM, per source |")
    keys = {"scan lines": "scan_lines", "random 20 %": "random"}
    assert len(rows) == 2
    for cells in rows:
        mean = protocols[next(v for k, v in keys.items() if cells[0].startswith(k))]["mean"]
        for cell, method in zip(cells[1:], methods):
            rmse, mae = (float(x) for x in cell.split("/"))
            assert (rmse, mae) == (round(mean[method]["rmse"], 1), round(mean[method]["mae"], 1)), (cells[0], method)


def test_readme_speed_table_is_the_json():
    """Every figure of the Speed table, formatted from the result file its row names."""
    step4 = _results("step4_variants.json")["rows"]
    job = _results("offline_job_bracket.json")
    e2e = _results("end_to_end.json")
    default, ipb = step4["default (column bracket)"]["median_ms"], step4["IP_Basic fast, OpenCV (Gaussian)"]["median_ms"]
    stages = e2e["stages_ms"]
    want = {
        "one frame, `jaxdepth.complete`": [f"{default:.2f} ms", f"{ipb:.2f} ms", f"{default / ipb:.2f}x", ""],
        "one frame, image-guided seeds (weight 50)": [
            f"{step4['guided, weight 50']['median_ms']:.2f} ms", "",
            f"{step4['guided, weight 50']['ratio_to_default']:.2f}x the default"],
        "960 frames,": [
            f"{job['median_seconds']['jaxdepth_complete']:.1f} s "
            f"({job['frames_per_second_median']['jaxdepth_complete']:.0f} frames/s)",
            f"{job['median_seconds']['ip_basic_loop']:.1f} s", f"{job['ratio_jaxdepth_over_ip_basic_median']:.2f}x"],
        "stages:": [" / ".join(f"{stages[k]:.2f}" for k in ("range_image_and_normals", "outlier_removal",
                                                             "distance_transform", "residual_and_smoothing")) + " ms"],
        "compile,": [f"{e2e['sgm_compile_s']:.1f} s"],
    }
    assert int(job["frames"]) == 960
    rows = _table("| what | jaxdepth | IP_Basic (OpenCV) |")
    assert len(rows) == len(want)
    for cells in rows:
        label = next(k for k in want if cells[0].startswith(k))
        assert [c for c in cells[1:4] if c] == [w for w in want[label] if w], (label, cells)
        assert cells[4].startswith("benchmarks/results/")


def _python_api_block() -> str:
    section = README.read_text().split("## Python API", 1)[1]
    return re.search(r"```python\n(.*?)```", section, flags=re.S).group(1)


@pytest.mark.slow  # the README block's programs: complete's doctest's (single and vmap), test_rig's
def test_readme_python_api_block_runs(tmp_path, monkeypatch):
    """Runs the README's API block on small inputs, files laid out as the block names them: the
    8 x 12 frame of ``complete``'s doctest (same shape, defaults and program), and the sweep of
    scenes.stereo_street with a rig JSON of its two cameras and SMALL_LIDAR (test_rig's program)."""
    from jaxdepth.io import write_depth_png
    from scenes import SMALL_LIDAR, stereo_street

    scene, cams = stereo_street()
    sparse = np.zeros((8, 12), np.float32)  # complete's doctest
    sparse[6, ::3], sparse[7, 1::3] = 5.0, 4.0
    K = np.array([[10.0, 0, 5.5], [0, 10.0, 3.5], [0, 0, 1]])
    (tmp_path / "velodyne_raw").mkdir()
    (tmp_path / "intrinsics").mkdir()
    write_depth_png(tmp_path / "velodyne_raw" / "0000000005.png", sparse)
    (tmp_path / "intrinsics" / "0000000005.txt").write_text(" ".join(f"{v:.6f}" for v in K.ravel()) + "\n")
    points = np.asarray(scene.points)[np.asarray(scene.valid)]
    np.concatenate([points, np.zeros((len(points), 1))], axis=1).astype(np.float32).tofile(tmp_path / "sweep.bin")
    lidar = {k: getattr(SMALL_LIDAR, k) for k in ("beams", "fov_up_deg", "fov_down_deg", "columns")}
    rig = {"lidar": lidar, "cameras": [{"name": f"cam{i}", "width": int(c.width), "height": int(c.height),
                                        "K": np.asarray(c.K, np.float64).tolist(),
                                        "T_cam_lidar": np.asarray(c.T_cam_lidar, np.float64).tolist()}
                                       for i, c in enumerate(cams)]}
    (tmp_path / "rig.json").write_text(json.dumps(rig))
    monkeypatch.chdir(tmp_path)
    scope: dict = {}
    exec(compile(_python_api_block(), "README.md (Python API)", "exec"), scope)  # noqa: S102
    assert scope["rig"].lidar == SMALL_LIDAR
    dense, batch, depths = (np.asarray(scope[k]) for k in ("dense", "batch", "depths"))
    h, w = int(cams[0].height), int(cams[0].width)
    assert dense.shape == (8, 12) and batch.shape == (2, 8, 12) and depths.shape == (2, h, w)
    np.testing.assert_array_equal(scope["sparse"], sparse)  # the block read the frame written above
    np.testing.assert_array_equal(dense[sparse > 0], sparse[sparse > 0])
    assert (dense > 0).all()  # every pixel has a nearest seed
    np.testing.assert_allclose(batch[1], dense, atol=1e-4)  # vmap equals the loop to float32 rounding
    assert (depths > 0).mean(axis=(1, 2)).min() > 0.5
    assert os.listdir(tmp_path)  # the block read its inputs from the working directory


def _nuscenes_block() -> str:
    section = README.read_text().split("**nuScenes dataroot**", 1)[1].split("**Any rig", 1)[0]
    return re.search(r"```python\n(.*?)```", section, flags=re.S).group(1)


def test_readme_nuscenes_devkit_block_writes_the_jobs_rig(tmp_path, monkeypatch):
    """Runs the README's devkit block against a stand-in ``nuscenes.nuscenes.NuScenes`` (random
    poses and intrinsics in the devkit's record layout): the rig JSON it writes holds each camera's
    K and SciPy's ``inv(C_cam) inv(E_cam) E_lidar C_lidar``, the chain the nuScenes job uses."""
    import sys
    import types

    from scipy.spatial.transform import Rotation

    from jaxdepth.io import read_rig_json
    from jaxdepth.io.nuscenes import NuScenesTables, camera_from_lidar

    rng = np.random.default_rng(0)
    channels = ("CAM_FRONT", "CAM_FRONT_RIGHT", "CAM_BACK_RIGHT", "CAM_BACK", "CAM_BACK_LEFT", "CAM_FRONT_LEFT")
    tables: dict = {"ego_pose": {}, "calibrated_sensor": {}, "sample_data": {}}

    def pose_record(table, token, **extra):
        q = rng.normal(size=4)    # any norm and sign: the devkit stores unit (w, x, y, z), pose_matrix normalises
        tables[table][token] = {"token": token, "translation": rng.uniform(-5, 5, 3).tolist(),
                                "rotation": q.tolist(), **extra}
        return token

    data = {}
    for channel in ("LIDAR_TOP",) + channels:
        extra = {} if channel == "LIDAR_TOP" else {"camera_intrinsic": [[rng.uniform(1000, 1300), 0, 800],
                                                                        [0, rng.uniform(1000, 1300), 450], [0, 0, 1]]}
        sd = {"token": f"sd_{channel}", "ego_pose_token": pose_record("ego_pose", f"ego_{channel}"),
              "calibrated_sensor_token": pose_record("calibrated_sensor", f"cs_{channel}", **extra),
              "width": 1600, "height": 900, "filename": f"samples/{channel}/x.pcd.bin"}
        tables["sample_data"][sd["token"]] = sd
        data[channel] = sd["token"]

    class NuScenes:  # the devkit's interface as the block uses it: .sample and .get(table, token)
        def __init__(self, version, dataroot):
            self.sample = [{"token": "s0", "data": data}]

        def get(self, table, token):
            return tables[table][token]

    devkit = types.ModuleType("nuscenes")
    devkit.nuscenes = types.ModuleType("nuscenes.nuscenes")
    devkit.nuscenes.NuScenes = NuScenes
    monkeypatch.setitem(sys.modules, "nuscenes", devkit)
    monkeypatch.setitem(sys.modules, "nuscenes.nuscenes", devkit.nuscenes)
    monkeypatch.chdir(tmp_path)
    exec(compile(_nuscenes_block(), "README.md (nuScenes devkit)", "exec"), {})  # noqa: S102

    def oracle(table, token):
        r = tables[table][token]
        T = np.eye(4)
        T[:3, :3] = Rotation.from_quat(np.roll(r["rotation"], -1)).as_matrix()   # SciPy: scalar last
        T[:3, 3] = r["translation"]
        return T

    rig = read_rig_json(tmp_path / "rig.json")
    assert [c.name for c in rig.cameras] == list(channels) and rig.lidar.beams == 32
    job_tables = NuScenesTables(dataroot=tmp_path, version="v1.0-mini", tables=tables, key_frames={})
    lidar = tables["sample_data"][data["LIDAR_TOP"]]
    for cam in rig.cameras:
        sd = tables["sample_data"][data[cam.name]]
        want = (np.linalg.inv(oracle("calibrated_sensor", sd["calibrated_sensor_token"]))
                @ np.linalg.inv(oracle("ego_pose", sd["ego_pose_token"])) @ oracle("ego_pose", lidar["ego_pose_token"])
                @ oracle("calibrated_sensor", lidar["calibrated_sensor_token"]))
        np.testing.assert_allclose(cam.T_cam_lidar, want, atol=1e-5)          # float32 in the JSON
        np.testing.assert_allclose(cam.T_cam_lidar, camera_from_lidar(job_tables, sd, lidar), atol=1e-5)
        np.testing.assert_allclose(cam.K, tables["calibrated_sensor"][sd["calibrated_sensor_token"]]["camera_intrinsic"],
                                   atol=1e-4)
        assert (cam.width, cam.height) == (1600, 900)
