"""Fuzz job over every reader: mutated real inputs give a clear error or the correct output.

Each reader gets ``CASES`` inputs made from real shared data (KITTI, nuScenes) by one
random mutation each (fixed seed): truncations, wrong column counts, float64 records,
rescaled values, NaN / inf, garbage bytes, wrong tokens, removed fields, and
value-preserving rewrites (line ends, white space, number formats, key order). The
reader (and its plausibility checks) runs in-process. A case passes when

* the reader raises a :class:`~jaxdepth.io.errors.JaxdepthError` whose message is one
  line naming the file, or
* it returns exactly what an independent decode gives: the unmutated content
  (NumPy / ``json`` / OpenCV decode of the real file), or, for a mutation that makes a
  different but legitimate input (a sweep with NaN points for missing returns, a
  record-aligned shorter sweep), the independent decode of the mutated content.

Value-preserving rewrites must be accepted. Unreadable files (permissions) are one
case per reader, skipped as root (root ignores chmod). The counts per reader are
printed and listed in docs/bad_input_checks.md.
"""

from __future__ import annotations

import json
import os
import re

import numpy as np
import pytest

from jaxdepth.io.errors import JaxdepthError
from tests.conftest import require_shared

SEED = 20261126
CASES = 2000
# A number token between white space (not the digits of a key such as R_rect_00).
_NUMBER = re.compile(r"(?<![^\s:])-?\d+(?:\.\d*)?(?:e[-+]\d+)?(?=\s|$)")

ERROR = "error"  # the mutation breaks the input: only an error is right
SAME = "same"  # value-preserving: must be accepted with the original output


class Case:
    """One mutated input: ``data`` (bytes), the name of the mutation, and what is right."""

    def __init__(self, kind: str, data: bytes, expect, **read):
        self.kind, self.data, self.expect, self.read = kind, data, expect, read


def _run(tmp_path, name, suffix, cases, read, reference, equal, *, must_accept_same=True):
    """Runs every case; returns {kind: count} and asserts the rule of the module docs."""
    counts: dict = {}
    wrong, refused = [], []
    path = tmp_path / f"{name}{suffix}"
    for i, case in enumerate(cases):
        # A new file each time: rewriting one in place (truncate) makes ext4 flush it to disk on
        # close (auto_da_alloc), ~8 ms per case instead of ~0.4 ms.
        path.unlink(missing_ok=True)
        path.write_bytes(case.data)
        counts[case.kind] = counts.get(case.kind, 0) + 1
        try:
            out = read(path, **case.read)
        except JaxdepthError as err:
            message = str(err)
            assert "\n" not in message and path.name in message, (case.kind, message)
            if case.expect is SAME and must_accept_same:
                refused.append((i, case.kind, message[:200]))
            continue
        if case.expect is ERROR:
            if not equal(out, reference):
                wrong.append((i, case.kind, "accepted a broken input with a different output"))
        elif case.expect is SAME:
            if not equal(out, reference):
                wrong.append((i, case.kind, "value-preserving rewrite read differently"))
        elif not equal(out, case.expect):
            wrong.append((i, case.kind, "output differs from the independent decode of the mutated file"))
    assert not wrong, f"{name}: {len(wrong)} silent wrong outputs, e.g. {wrong[:5]}"
    assert not refused, f"{name}: {len(refused)} value-preserving inputs refused, e.g. {refused[:3]}"
    total = sum(counts.values())
    print(f"\nfuzz {name}: {total} inputs: " + ", ".join(f"{k} {v}" for k, v in sorted(counts.items())))
    return total


def _permission_case(tmp_path, name, data, read):
    """One unreadable file: an error, or a skip note as root."""
    if os.geteuid() == 0:
        print(f"\nfuzz {name}: permission variant skipped (running as root: chmod does not stop root)")
        return 0
    path = tmp_path / f"unreadable_{name}"
    path.write_bytes(data)
    path.chmod(0)
    try:
        with pytest.raises(JaxdepthError, match="cannot read|permission|Permission"):
            read(path)
    finally:
        path.chmod(0o600)
    return 1


# ------------------------------------------------------------------ LiDAR sweeps


def _sweep_cases(rng, records: np.ndarray, *, columns: int, ring: bool):
    """Mutations of an (N, columns) float32 record array."""
    n = records.shape[0]
    raw = records.astype("<f4").tobytes()
    record = 4 * columns
    kinds = ["truncate", "columns", "float64", "scale", "nan_some", "nan_all", "inf_some", "garbage", "zeros",
             "intensity", "axes", "same", "far"] + (["ring_fraction", "ring_shuffle", "ring_huge"] if ring else [])
    for _ in range(CASES):
        kind = kinds[rng.integers(len(kinds))]
        if kind == "truncate":
            cut = int(rng.integers(0, len(raw)))
            if rng.random() < 0.3:
                cut -= cut % record  # record-aligned: a shorter, legitimate sweep
            expect = ERROR if cut == 0 or cut % record else _decode(raw[:cut], columns)
            yield Case(kind, raw[:cut], expect, columns=columns)
        elif kind == "columns":
            wrong = int(rng.choice([c for c in (3, 4, 5, 6, 7) if c != columns]))
            yield Case(kind, raw, ERROR, columns=wrong)
        elif kind == "float64":
            yield Case(kind, records.astype("<f8").tobytes(), ERROR, columns=int(rng.choice([columns, 3, 4, 5])))
        elif kind == "scale":
            s = float(rng.choice([1e3, 1e-3, 1e6, 1e-6, 1e4]))
            m = records.copy()
            m[:, :3] *= s
            yield Case(kind, m.astype("<f4").tobytes(), ERROR, columns=columns)
        elif kind in ("nan_some", "inf_some"):
            m = records.copy()
            rows = rng.random(n) < rng.uniform(0.001, 0.3)
            m[rows, int(rng.integers(3))] = np.nan if kind == "nan_some" else np.inf
            yield Case(kind, m.tobytes(), _decode(m.tobytes(), columns), columns=columns)
        elif kind == "nan_all":
            m = records.copy()
            m[:, int(rng.integers(3))] = np.nan
            yield Case(kind, m.tobytes(), ERROR, columns=columns)
        elif kind == "garbage":
            yield Case(kind, rng.integers(0, 256, len(raw), dtype=np.uint8).tobytes(), ERROR, columns=columns)
        elif kind == "zeros":
            yield Case(kind, bytes(len(raw)), ERROR, columns=columns)
        elif kind == "intensity":
            m = records.copy()
            m[:, 3] = rng.choice([1e9, -1e6, np.nan])
            yield Case(kind, m.tobytes(), ERROR, columns=columns)
        elif kind == "axes":  # z swapped with x or y: a sweep on its side
            m = records.copy()
            j = int(rng.integers(2))
            m[:, [j, 2]] = m[:, [2, j]]
            yield Case(kind, m.tobytes(), ERROR, columns=columns)
        elif kind == "same":
            yield Case(kind, raw, SAME, columns=columns)
        elif kind == "far":  # some points pushed along their ray beyond any LiDAR's range (or just inside)
            m = records.copy()
            rows = rng.random(n) < rng.uniform(0.0005, 0.2)
            rows[int(rng.integers(n))] = True
            rows &= np.any(m[:, :3] != 0, axis=1)
            target = rng.choice([900.0, 1.5e3, 1e5, 1e6, 1e30], size=int(rows.sum()))
            scale = target / np.linalg.norm(m[rows, :3].astype(np.float64), axis=1)
            m[rows, :3] = (m[rows, :3] * scale[:, None]).astype(np.float32)
            yield Case(kind, m.tobytes(), _decode_far(m.tobytes(), columns), columns=columns)
        elif kind == "ring_fraction":
            m = records.copy()
            m[:, 4] += 0.5
            yield Case(kind, m.tobytes(), ERROR, columns=columns)
        elif kind == "ring_shuffle":
            m = records.copy()
            m[:, 4] = rng.permutation(m[:, 4])
            yield Case(kind, m.tobytes(), ERROR, columns=columns)
        else:  # ring_huge
            m = records.copy()
            m[:, 4] = rng.integers(2000, 10 ** 6, n)
            yield Case(kind, m.tobytes(), ERROR, columns=columns)


def _decode(raw: bytes, columns: int):
    """Independent decode: (points, extra) of little-endian float32 records."""
    a = np.frombuffer(raw, "<f4").reshape(-1, columns)
    return a[:, :3], a[:, 3:]


def _decode_far(raw: bytes, columns: int, limit_m: float = 1000.0):
    """Independent decode of a sweep with far points: x, y, z NaN where the float64 range exceeds the limit."""
    points, extra = _decode(raw, columns)
    far = np.sqrt((points.astype(np.float64) ** 2).sum(axis=1)) > limit_m
    return np.where(far[:, None], np.float32(np.nan), points), extra


def _equal_sweeps(out, ref) -> bool:
    return all(np.array_equal(np.asarray(x), np.asarray(y), equal_nan=True) for x, y in zip(out, ref)) and \
        np.asarray(out[0]).shape == np.asarray(ref[0]).shape


def _subsample(records: np.ndarray, size: int = 2048) -> np.ndarray:
    """Every k-th real record (all azimuths), about ``size`` of them."""
    step = max(1, records.shape[0] // size)
    return np.ascontiguousarray(records[::step][:size])


def test_fuzz_kitti_velodyne_bin(tmp_path):
    from jaxdepth.io.points import read_points
    src = require_shared("kitti", "drive_0001_frame05", "lidar_data.bin")
    records = _subsample(np.fromfile(src, "<f4").reshape(-1, 4))
    rng = np.random.default_rng(SEED)
    reference = _decode(records.tobytes(), 4)
    total = _run(tmp_path, "velodyne", ".bin", _sweep_cases(rng, records, columns=4, ring=False), read_points,
                 reference, _equal_sweeps)
    total += _permission_case(tmp_path, "velodyne.bin", records.tobytes(), read_points)
    assert total >= CASES


def test_fuzz_nuscenes_pcd_bin(tmp_path):
    from jaxdepth.io.points import read_points
    sample = require_shared("nuscenes", "sample")
    src = next(sample.glob("*.pcd.bin"))
    records = _subsample(np.fromfile(src, "<f4").reshape(-1, 5))
    rng = np.random.default_rng(SEED + 1)
    reference = _decode(records.tobytes(), 5)
    total = _run(tmp_path, "lidar_top", ".pcd.bin", _sweep_cases(rng, records, columns=5, ring=True), read_points,
                 reference, _equal_sweeps)
    assert total >= CASES


def test_nuscenes_layout_checks_hold_on_the_full_real_files():
    """The checks accept both real sweeps in their own layout and refuse every other layout."""
    from jaxdepth.io.plausibility import LAYOUTS, decode_layout, layout_problem
    kitti = require_shared("kitti", "drive_0001_frame05", "lidar_data.bin").read_bytes()
    nusc = next(require_shared("nuscenes", "sample").glob("*.pcd.bin")).read_bytes()
    for raw, right in ((kitti, ("<f4", 4)), (nusc, ("<f4", 5))):
        for dtype, columns, _ in LAYOUTS:
            array = decode_layout(raw, dtype, columns)
            if array is None:
                continue
            problem = layout_problem(array)
            assert (problem is None) == ((dtype, columns) == right), (dtype, columns, problem)


# ------------------------------------------------------------------ depth PNGs


def _png(depth_u16: np.ndarray, level: int = 3) -> bytes:
    import cv2
    ok, buf = cv2.imencode(".png", depth_u16, [cv2.IMWRITE_PNG_COMPRESSION, level])
    assert ok
    return buf.tobytes()


def test_fuzz_depth_png(tmp_path):
    import cv2

    from jaxdepth.io.plausibility import read_checked_depth_png
    src = require_shared("kitti", "drive_0001_frame05", "velodyne_raw_image_02.png")
    u16 = np.ascontiguousarray(cv2.imread(str(src), cv2.IMREAD_UNCHANGED)[200:375, 300:812])
    reference = u16.astype(np.float32) / 256  # independent decode: OpenCV, metres = value / 256
    raw = _png(u16)
    rng = np.random.default_rng(SEED + 2)
    metres = u16.astype(np.float64) / 256
    # The rescaled images are the same every time they are drawn: each is encoded once.
    rescaled = {
        "millimetres": lambda: _png(np.clip(np.rint(metres * 1000), 0, 65535).astype(np.uint16)),
        "integer_metres": lambda: _png((np.rint(metres) * 256).astype(np.uint16)),
        "decimetres": lambda: _png(np.rint(metres * 10).astype(np.uint16)),
        "uint8": lambda: _png(np.clip(metres, 0, 255).astype(np.uint8)),
        "rgb": lambda: _png(np.repeat(u16[..., None], 3, axis=2)),
        "zeros": lambda: _png(np.zeros_like(u16)),
    }
    encoded: dict = {}

    def once(key, encode):
        if key not in encoded:
            encoded[key] = encode()
        return encoded[key]

    def cases():
        kinds = ["truncate", "flip", "millimetres", "integer_metres", "decimetres", "uint8", "rgb", "level",
                 "zeros", "garbage"]
        for _ in range(CASES):
            kind = kinds[rng.integers(len(kinds))]
            if kind == "truncate":
                yield Case(kind, raw[:int(rng.integers(0, len(raw)))], ERROR)
            elif kind == "flip":
                data = bytearray(raw)
                data[int(rng.integers(len(data)))] ^= 1 << int(rng.integers(8))
                yield Case(kind, bytes(data), ERROR)
            elif kind == "level":
                level = int(rng.integers(0, 10))
                yield Case(kind, once(("level", level), lambda: _png(u16, level)), SAME)
            elif kind == "zeros":  # an empty depth image is legitimate: read as zeros
                yield Case(kind, once(kind, rescaled[kind]), np.zeros(u16.shape, np.float32))
            elif kind in rescaled:
                yield Case(kind, once(kind, rescaled[kind]), ERROR)
            else:
                yield Case(kind, rng.integers(0, 256, len(raw), dtype=np.uint8).tobytes(), ERROR)

    def read(path):
        return read_checked_depth_png(path, role="LiDAR input")

    total = _run(tmp_path, "depth", ".png", cases(), read, reference,
                 lambda a, b: a.shape == b.shape and np.array_equal(a, b))
    total += _permission_case(tmp_path, "depth.png", raw, read)
    assert total >= CASES


# ------------------------------------------------------------------ text and JSON calibration


def _text_cases(rng, text: str, *, reformat_numbers: bool = True):
    """Mutations of a calibration text: breaking ones expect an error or the same output (an unread
    field), value-preserving ones must give the same output."""
    lines = text.splitlines(keepends=True)
    numbers = list(_NUMBER.finditer(text))
    kinds = ["truncate", "drop_line", "duplicate_line", "bad_token", "crlf", "spaces", "reformat", "garbage",
             "drop_token"]
    for _ in range(CASES):
        kind = kinds[rng.integers(len(kinds))]
        if kind == "truncate":
            yield Case(kind, text[:int(rng.integers(0, len(text)))].encode(), ERROR)
        elif kind == "drop_line":
            j = int(rng.integers(len(lines)))
            yield Case(kind, "".join(lines[:j] + lines[j + 1:]).encode(), ERROR)
        elif kind == "duplicate_line":
            j = int(rng.integers(len(lines)))
            yield Case(kind, "".join(lines[:j + 1] + lines[j:]).encode(), ERROR)
        elif kind in ("bad_token", "drop_token"):
            m = numbers[int(rng.integers(len(numbers)))]
            token = "" if kind == "drop_token" else str(rng.choice(["nan", "inf", "-inf", "abc", "1e999", "--1",
                                                                      "0x1p3", "1,,2"]))
            yield Case(kind, (text[:m.start()] + token + text[m.end():]).encode(), ERROR)
        elif kind == "crlf":
            yield Case(kind, text.replace("\n", "\r\n").encode(), SAME)
        elif kind == "spaces":
            yield Case(kind, re.sub(r" ", lambda _: " " * int(rng.integers(1, 4)), text).encode(), SAME)
        elif kind == "reformat":
            if not reformat_numbers:
                yield Case(kind, text.encode(), SAME)
                continue
            fmt = str(rng.choice(["{:.9e}", "{!r}", "{:.12g}"]))
            yield Case(kind, _NUMBER.sub(lambda m: fmt.format(float(m.group())), text).encode(), SAME)
        else:
            data = bytearray(text.encode())
            data[int(rng.integers(len(data)))] = int(rng.integers(128, 256))
            yield Case(kind, bytes(data), ERROR)


def test_fuzz_intrinsics_txt(tmp_path):
    from jaxdepth.io.calib import read_intrinsics_txt
    text = "7.215377e+02 0.000000e+00 5.965593e+02\n0.000000e+00 7.215377e+02 1.498540e+02\n0.0 0.0 1.0\n"
    reference = np.array([float(t) for t in text.split()], np.float32).reshape(3, 3)  # independent parse
    rng = np.random.default_rng(SEED + 3)
    total = _run(tmp_path, "intrinsics", ".txt", _text_cases(rng, text), read_intrinsics_txt, reference,
                 lambda a, b: np.array_equal(a, b))
    total += _permission_case(tmp_path, "intrinsics.txt", text.encode(), read_intrinsics_txt)
    assert total >= CASES


def test_fuzz_kitti_raw_calibration_txt(tmp_path):
    from jaxdepth.io.calib import read_kitti_raw_calib
    frame = require_shared("kitti", "drive_0001_frame05")
    c2c_text = (frame / "calib_cam_to_cam.txt").read_text()
    v2c = frame / "calib_velo_to_cam.txt"
    reference = read_kitti_raw_calib(frame / "calib_cam_to_cam.txt", v2c)
    # Independent check of the reference: camera 2's K is P_rect_02's left 3x3 block as printed.
    p2 = [float(t) for t in re.search(r"^P_rect_02:(.*)$", c2c_text, re.M).group(1).split()]
    np.testing.assert_array_equal(reference["cameras"][2]["K"], np.asarray(p2, np.float32).reshape(3, 4)[:, :3])

    def equal(a, b):
        return all(np.array_equal(a["cameras"][i][k], b["cameras"][i][k]) for i in range(4)
                   for k in ("K", "T_cam_lidar", "width", "height")) and a["baseline_m"] == b["baseline_m"]

    rng = np.random.default_rng(SEED + 4)
    total = _run(tmp_path, "calib_cam_to_cam", ".txt", _text_cases(rng, c2c_text),
                 lambda path: read_kitti_raw_calib(path, v2c), reference, equal)
    total += _permission_case(tmp_path, "calib_cam_to_cam.txt", c2c_text.encode(),
                              lambda path: read_kitti_raw_calib(path, v2c))
    assert total >= CASES


def _leaves(doc, path=()):
    """Paths of every number in a JSON document."""
    if isinstance(doc, dict):
        for k, v in doc.items():
            yield from _leaves(v, path + (k,))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            yield from _leaves(v, path + (i,))
    elif isinstance(doc, (int, float)) and not isinstance(doc, bool):
        yield path


def _set(doc, path, value):
    import copy
    doc = copy.deepcopy(doc)
    node = doc
    for k in path[:-1]:
        node = node[k]
    if value is _DELETE:
        del node[path[-1]]
    else:
        node[path[-1]] = value
    return doc


_DELETE = object()


def _json_cases(rng, doc: dict, *, required: list):
    text = json.dumps(doc, indent=2)
    leaves = list(_leaves(doc))
    outside = np.flatnonzero(_outside_strings(text))
    kinds = ["truncate", "bad_value", "drop_required", "reindent", "reorder", "garbage", "wrong_shape"]
    for _ in range(CASES):
        kind = kinds[rng.integers(len(kinds))]
        if kind == "truncate":
            cut = int(rng.integers(0, len(text)))
            expect = SAME if not text[cut:].strip() else ERROR
            yield Case(kind, text[:cut].encode(), expect)
        elif kind == "bad_value":
            path = leaves[int(rng.integers(len(leaves)))]
            value = [float("nan"), float("inf"), "x", None, [], {}, True, 1e400][int(rng.integers(8))]
            yield Case(kind, json.dumps(_set(doc, path, value)).encode(), ERROR)
        elif kind == "wrong_shape":
            path = leaves[int(rng.integers(len(leaves)))]
            yield Case(kind, json.dumps(_set(doc, path[:-1], [1.0, 2.0])).encode(), ERROR)
        elif kind == "drop_required":
            path = required[int(rng.integers(len(required)))]
            yield Case(kind, json.dumps(_set(doc, path, _DELETE)).encode(), ERROR)
        elif kind == "reindent":
            yield Case(kind, json.dumps(doc, indent=int(rng.integers(0, 5)), separators=(",", ": ")).encode(), SAME)
        elif kind == "reorder":
            yield Case(kind, json.dumps(_shuffled(doc, rng)).encode(), SAME)
        else:  # a structural byte outside string literals (inside one it is a legitimate other name)
            data = bytearray(text.encode())
            data[int(outside[rng.integers(len(outside))])] = int(rng.choice([0x7B, 0x22, 0x5D, 0xFF, 0x2C]))
            yield Case(kind, bytes(data), ERROR)


def _outside_strings(text: str) -> np.ndarray:
    """(len,) bool: the character is not part of a JSON string literal (ASCII text)."""
    mask = np.ones(len(text), bool)
    inside = escaped = False
    for i, ch in enumerate(text):
        if inside:
            mask[i] = False
            if escaped:
                escaped = False
            elif ch == "\\":
                escaped = True
            elif ch == '"':
                inside = False
        elif ch == '"':
            inside, mask[i] = True, False
    return mask


def _shuffled(doc, rng):
    if isinstance(doc, dict):
        keys = list(doc)
        order = rng.permutation(len(keys))
        return {keys[i]: _shuffled(doc[keys[i]], rng) for i in order}
    if isinstance(doc, list):
        return [_shuffled(v, rng) for v in doc]
    return doc


def test_fuzz_rig_json(tmp_path):
    from jaxdepth.io.rig import read_rig_json, rig_from_kitti_raw, write_rig_json
    frame = require_shared("kitti", "drive_0001_frame05")
    rig = rig_from_kitti_raw(frame / "calib_cam_to_cam.txt", frame / "calib_velo_to_cam.txt")
    write_rig_json(tmp_path / "orig.json", rig)
    doc = json.loads((tmp_path / "orig.json").read_text())
    reference = read_rig_json(tmp_path / "orig.json")
    # Independent check of the reference: the JSON's K and T, read with json + NumPy.
    for cam, entry in zip(reference.cameras, doc["cameras"]):
        np.testing.assert_array_equal(cam.K, np.asarray(entry["K"], np.float32))
    required = [("cameras",)] + [("cameras", i, k) for i in range(len(doc["cameras"]))
                                 for k in ("K", "T_cam_lidar", "width", "height", "name")]
    rng = np.random.default_rng(SEED + 5)
    total = _run(tmp_path, "rig", ".json", _json_cases(rng, doc, required=required), read_rig_json, reference,
                 lambda a, b: a == b)
    total += _permission_case(tmp_path, "rig.json", json.dumps(doc).encode(), read_rig_json)
    assert total >= CASES


def test_fuzz_nuscenes_calibration_json(tmp_path):
    from jaxdepth.io.rig import rig_from_nuscenes_calibration
    src = require_shared("nuscenes", "sample", "calibration.json")
    full = json.loads(src.read_text())
    doc = {"cameras": {name: {k: full["cameras"][name][k] for k in ("cam2img", "lidar2cam")}
                       for name in list(full["cameras"])[:2]}}
    (tmp_path / "orig.json").write_text(json.dumps(doc))
    reference = rig_from_nuscenes_calibration(tmp_path / "orig.json")
    for cam, (name, entry) in zip(reference.cameras, doc["cameras"].items()):
        np.testing.assert_allclose(cam.K, np.asarray(entry["cam2img"], np.float64)[:3, :3], rtol=1e-6)
    required = [("cameras",)] + [("cameras", n, k) for n in doc["cameras"] for k in ("cam2img", "lidar2cam")]
    rng = np.random.default_rng(SEED + 6)
    def equal(a, b):  # cameras come in file order: a reordered object is the same rig
        return a.lidar == b.lidar and sorted(a.cameras, key=lambda c: c.name) == sorted(b.cameras,
                                                                                       key=lambda c: c.name)

    total = _run(tmp_path, "calibration", ".json", _json_cases(rng, doc, required=required),
                 rig_from_nuscenes_calibration, reference, equal)
    assert total >= CASES


def test_fuzz_extrinsic_txt(tmp_path):
    from jaxdepth.io.calib import read_extrinsic_txt
    text = ("7.533745e-03 -9.999714e-01 -6.166020e-04 -4.069766e-03\n"
            "1.480249e-02 7.280733e-04 -9.998902e-01 -7.631618e-02\n"
            "9.998621e-01 7.523790e-03 1.480755e-02 -2.717806e-01\n")
    top = np.array([float(t) for t in text.split()], np.float64).reshape(3, 4)
    reference = np.vstack([top, [0, 0, 0, 1]]).astype(np.float32)
    rng = np.random.default_rng(SEED + 7)
    total = _run(tmp_path, "extrinsic", ".txt", _text_cases(rng, text), read_extrinsic_txt, reference,
                 lambda a, b: np.array_equal(a, b))
    assert total >= CASES


# ------------------------------------------------------------------ calibrations against the sweep


GEOMETRY_CASES = 400


def _rotation(axis: int, degrees: float) -> np.ndarray:
    """(4, 4) rotation about x (0), y (1) or z (2), an analytic oracle for the legitimate cases."""
    c, s = np.cos(np.radians(degrees)), np.sin(np.radians(degrees))
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    R = np.eye(4)
    R[i, i] = R[j, j] = c
    R[i, j], R[j, i] = -s, s
    return R


def _up_axis_moves(T: np.ndarray) -> float:
    """Degrees between the camera's up axis under T and under inv(T), from the matrix alone."""
    R = np.asarray(T, np.float64)[:3, :3]
    return float(np.degrees(np.arccos(np.clip(R[1] @ R[:, 1], -1.0, 1.0))))


def _geometry_cases(rng, cameras: dict, *, invertible: list):
    """Mutations of {name: (K, T, width, height)}: inverted T, K scaled for another image size (x 0.5,
    2, 0.25, 4; or x 3, the image then holds a third of K's view: "oversized"), the image size swapped
    must be refused with the named cause; a camera turned about the vertical, tilted by up to 14 deg
    in roll and 6 deg in pitch (KITTI's cameras pitched up by 8 deg or more see the LiDAR's points only
    at the bottom edge: refused, docs/bad_input_checks.md), or resized together with its K must be
    accepted."""
    kinds = ["inverted", "scaled", "oversized", "swapped", "turned", "resized", "same"]
    for _ in range(GEOMETRY_CASES):
        kind = kinds[rng.integers(len(kinds))]
        new = {n: (np.array(K, np.float64), np.array(T, np.float64), w, h) for n, (K, T, w, h) in cameras.items()}
        if kind == "inverted":
            chosen = [n for n in invertible if rng.random() < 0.5] or [invertible[int(rng.integers(len(invertible)))]]
            for n in chosen:
                K, T, w, h = new[n]
                new[n] = (K, np.linalg.inv(T), w, h)
            yield kind, new, "T_cam_lidar looks inverted"
        elif kind == "scaled":
            s = float(rng.choice([0.5, 2.0, 0.25, 4.0]))
            for n in [n for n in new if rng.random() < 0.5] or list(new)[:1]:
                K, T, w, h = new[n]
                K[:2] *= s
                new[n] = (K, T, w, h)
            yield kind, new, f"K seems scaled by {s:g} for this image size"
        elif kind == "oversized":
            for n in [n for n in new if rng.random() < 0.5] or list(new)[:1]:
                K, T, w, h = new[n]
                K[:2] *= 3.0
                new[n] = (K, T, w, h)
            # the principal point test names the nearest of its factors where it applies
            yield kind, new, ("of the sweep's points in K's view land in the", "K seems scaled by")
        elif kind == "swapped":  # every camera: the nuScenes reader takes one image size for the file
            for n, (K, T, w, h) in new.items():
                new[n] = (K, T, h, w)
            yield kind, new, "seems swapped"
        elif kind == "turned":
            for n, (K, T, w, h) in new.items():
                tilt = _rotation(0, rng.uniform(-6, 6)) @ _rotation(2, rng.uniform(-14, 14))  # pitch, roll
                new[n] = (K, tilt @ T @ _rotation(2, rng.uniform(-180, 180)), w, h)
            yield kind, new, None
        elif kind == "resized":
            s = float(rng.choice([0.5, 0.25, 2.0]))
            for n, (K, T, w, h) in new.items():
                K[:2] *= s
                new[n] = (K, T, int(round(w * s)), int(round(h * s)))
            yield kind, new, None
        else:
            yield kind, new, None


def _run_geometry(tmp_path, monkeypatch, name, cases, write, read, points):
    """Writes each case with ``write``, reads it back with the dataset's reader, checks it against the sweep.

    Every case checks the same sweep, so its ground (``sweep_ground``, a function of the points alone) is
    fitted once and handed to every ``check_rig_geometry`` call (about 9 ms of CPU a fit); the rest of the
    check runs in full on each case."""
    from jaxdepth.io import plausibility
    from jaxdepth.io.plausibility import check_rig_geometry
    fit = plausibility.sweep_ground
    ground = fit(points)
    assert ground is not None       # a street sweep: the ground and projection checks apply

    def same_sweep_ground(p):
        return ground if p is points else fit(p)

    monkeypatch.setattr(plausibility, "sweep_ground", same_sweep_ground)
    counts: dict = {}
    wrong = []
    for i, (kind, cameras, cause) in enumerate(cases):
        counts[kind] = counts.get(kind, 0) + 1
        path = tmp_path / f"{name}_{i}.json"
        write(path, cameras)
        rig = read(path)
        try:
            check_rig_geometry(points, rig.cameras, path=path)
        except JaxdepthError as err:
            message = str(err)
            assert "\n" not in message and path.name in message
            causes = (cause,) if isinstance(cause, str) else cause
            if cause is None or not any(c in message for c in causes):
                wrong.append((i, kind, message[:160]))
            continue
        if cause is not None:
            wrong.append((i, kind, "accepted"))
    assert not wrong, f"{name}: {len(wrong)} wrong outcomes, e.g. {wrong[:4]}"
    print(f"\nfuzz {name} geometry: {sum(counts.values())} calibrations: "
          + ", ".join(f"{k} {v}" for k, v in sorted(counts.items())))


def test_fuzz_nuscenes_calibration_geometry(tmp_path, monkeypatch):
    """calibration.json with inverted lidar2cam / rescaled cam2img, read by the reader, checked against the sweep."""
    from jaxdepth.io.rig import rig_from_nuscenes_calibration
    sample = require_shared("nuscenes", "sample")
    full = json.loads((sample / "calibration.json").read_text())
    points = np.fromfile(next(sample.glob("*.pcd.bin")), "<f4").reshape(-1, 5)[:, :3]
    cameras = {n: (np.asarray(c["cam2img"], np.float64)[:3, :3], np.asarray(c["lidar2cam"], np.float64), 1600, 900)
               for n, c in full["cameras"].items()}
    invertible = [n for n, (_, T, _, _) in cameras.items() if _up_axis_moves(T) > 60]
    assert len(invertible) == 5  # all but CAM_BACK, whose rotation is its own inverse (docs/bad_input_checks.md)
    sizes = {}

    def write(path, cams):
        sizes.clear()
        sizes.update({n: (w, h) for n, (_, _, w, h) in cams.items()})
        path.write_text(json.dumps({"cameras": {n: {"cam2img": K.tolist(), "lidar2cam": T.tolist()}
                                                for n, (K, T, _, _) in cams.items()}}))

    def read(path):  # one image size for the file, as the reader takes it
        (w, h), = set(sizes.values())
        return rig_from_nuscenes_calibration(path, width=w, height=h)

    _run_geometry(tmp_path, monkeypatch, "nuscenes", _geometry_cases(np.random.default_rng(SEED + 8), cameras,
                                                        invertible=invertible), write, read, points)


def test_fuzz_kitti_rig_geometry(tmp_path, monkeypatch):
    """The KITTI rig JSON (cameras 2, 3) with inverted / rescaled calibrations, checked against the sweep."""
    from jaxdepth.io.rig import RigCamera, read_rig_json, rig_from_kitti_raw, rig_to_json_text
    frame = require_shared("kitti", "drive_0001_frame05")
    rig = rig_from_kitti_raw(frame / "calib_cam_to_cam.txt", frame / "calib_velo_to_cam.txt")
    points = np.fromfile(frame / "lidar_data.bin", "<f4").reshape(-1, 4)[:, :3]
    cameras = {c.name: (c.K, c.T_cam_lidar, c.width, c.height) for c in rig.cameras}
    invertible = [n for n, (_, T, _, _) in cameras.items() if _up_axis_moves(T) > 60]
    assert len(invertible) == 2

    def write(path, cams):  # write_rig_json's text without its atomic write (two fsyncs a case; test_io_atomic's)
        import dataclasses
        path.write_text(rig_to_json_text(dataclasses.replace(rig, cameras=tuple(
            RigCamera(n, w, h, K.astype(np.float32), T.astype(np.float32)) for n, (K, T, w, h) in cams.items()))))

    _run_geometry(tmp_path, monkeypatch, "kitti", _geometry_cases(np.random.default_rng(SEED + 9), cameras,
                                                     invertible=invertible), write, read_rig_json, points)
