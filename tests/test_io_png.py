"""KITTI depth PNG reader / writer."""

from __future__ import annotations

import pathlib
import struct
import zlib

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from jaxdepth.io import InputError, OutputError, encode_depth_uint16, read_depth_png, write_depth_png

_HYP = settings(deadline=None, max_examples=30, suppress_health_check=[HealthCheck.function_scoped_fixture])


def test_reads_official_velodyne_raw(kitti_frame):
    path = kitti_frame / "velodyne_raw_image_02.png"
    depth = read_depth_png(path)
    oracle = cv2.imread(str(path), cv2.IMREAD_ANYDEPTH)
    assert oracle.dtype == np.uint16
    assert depth.dtype == np.float32 and depth.shape == (375, 1242)
    np.testing.assert_array_equal(depth, oracle.astype(np.float64) / 256.0)
    assert int((depth > 0).sum()) == 19154  # data README
    assert 0 < depth[depth > 0].min() and depth.max() < 256


def test_every_uint16_value_reads_as_its_exact_metres(tmp_path):
    """Each of the 65,536 stored values v decodes to exactly v / 256 (float64 oracle, PNG written by OpenCV)."""
    values = np.arange(1 << 16, dtype=np.uint16).reshape(256, 256)
    path = tmp_path / "all.png"
    assert cv2.imwrite(str(path), values)
    depth = read_depth_png(path)
    assert depth.dtype == np.float32
    np.testing.assert_array_equal(depth.astype(np.float64), values.astype(np.float64) / 256.0)


def test_groundtruth_facts(kitti_frame):
    gt = read_depth_png(kitti_frame / "groundtruth_image_02.png")
    assert int((gt > 0).sum()) == 90839
    assert not gt[:119].any()  # rows 0-118 empty (data README)


def test_rejects_colour_8bit_and_jpeg(kitti_frame, nuscenes_sample, tmp_path):
    with pytest.raises(InputError, match=r"image_02\.png: expected a 16-bit greyscale PNG .*got a 8-bit RGB colour PNG"):
        read_depth_png(kitti_frame / "image_02.png")
    grey8 = tmp_path / "grey8.png"
    cv2.imwrite(str(grey8), np.zeros((4, 5), np.uint8))
    with pytest.raises(InputError, match=r"grey8\.png: .*got a 8-bit greyscale PNG"):
        read_depth_png(grey8)
    rgb16 = tmp_path / "rgb16.png"
    cv2.imwrite(str(rgb16), np.zeros((4, 5, 3), np.uint16))
    with pytest.raises(InputError, match=r"rgb16\.png: .*got a 16-bit RGB colour PNG"):
        read_depth_png(rgb16)
    jpeg = next(nuscenes_sample.glob("*CAM_FRONT__*.jpg"))
    with pytest.raises(InputError, match=r"CAM_FRONT.*\.jpg: not a PNG file"):
        read_depth_png(jpeg)


def test_missing_empty_folder(tmp_path):
    with pytest.raises(InputError, match=r"nope\.png: file not found"):
        read_depth_png(tmp_path / "nope.png")
    (tmp_path / "empty.png").write_bytes(b"")
    with pytest.raises(InputError, match=r"empty\.png: file is empty"):
        read_depth_png(tmp_path / "empty.png")
    with pytest.raises(InputError, match=r"is a folder"):
        read_depth_png(tmp_path)


def test_header_checksum_and_size(tmp_path, kitti_frame):
    data = bytearray((kitti_frame / "velodyne_raw_image_02.png").read_bytes())
    bad = bytearray(data)
    bad[17] ^= 0xFF  # width byte: IHDR CRC no longer matches
    (tmp_path / "a.png").write_bytes(bytes(bad))
    with pytest.raises(InputError, match=r"a\.png: corrupt PNG: IHDR checksum mismatch"):
        read_depth_png(tmp_path / "a.png")
    # A consistent header with an absurd size is refused before decoding.
    ihdr = struct.pack(">IIBBBBB", 1 << 20, 1 << 20, 16, 0, 0, 0, 0)
    chunk = struct.pack(">I", 13) + b"IHDR" + ihdr + struct.pack(">I", zlib.crc32(b"IHDR" + ihdr))
    (tmp_path / "b.png").write_bytes(bytes(data[:8]) + chunk + bytes(data[33:]))
    with pytest.raises(InputError, match=r"b\.png: corrupt PNG: image size 1048576x1048576"):
        read_depth_png(tmp_path / "b.png")


@pytest.fixture(scope="module")
def real_png_bytes(kitti_frame) -> bytes:
    return (kitti_frame / "velodyne_raw_image_02.png").read_bytes()


@pytest.mark.parametrize("keep", [0, 5, 8, 20, 33, 40, 100, 1000, -1000, -13, -12, -1])
def test_truncations_are_input_errors(tmp_path, real_png_bytes, keep):
    path = tmp_path / "t.png"
    path.write_bytes(real_png_bytes[:keep])
    if keep in (-12, -1):
        # Only the IEND chunk (or part of it) is missing: all pixel data is
        # present and decodes exactly; anything else is an InputError.
        try:
            got = read_depth_png(path)
        except InputError:
            return
        np.testing.assert_array_equal(got, read_depth_png(_write(tmp_path / "ok.png", real_png_bytes)))
        return
    with pytest.raises(InputError, match=r"t\.png: "):
        read_depth_png(path)


def _write(path: pathlib.Path, data: bytes) -> pathlib.Path:
    path.write_bytes(data)
    return path


@_HYP
@given(cut=st.integers(min_value=0, max_value=200_000))
def test_fuzz_truncation(tmp_path, real_png_bytes, cut):
    path = _write(tmp_path / "f.png", real_png_bytes[: min(cut, len(real_png_bytes) - 13)])
    with pytest.raises(InputError):
        read_depth_png(path)


@_HYP
@given(data=st.binary(max_size=512), with_signature=st.booleans())
def test_fuzz_random_bytes(tmp_path, data, with_signature):
    path = _write(tmp_path / "r.png", (b"\x89PNG\r\n\x1a\n" if with_signature else b"") + data)
    with pytest.raises(InputError):
        read_depth_png(path)


@_HYP
@given(flips=st.lists(st.tuples(st.integers(0, 10**9), st.integers(1, 255)), min_size=1, max_size=4))
def test_fuzz_byte_flips(tmp_path, real_png_bytes, flips):
    """Corrupting bytes gives an InputError or (harmless chunks) a well-formed depth map."""
    data = bytearray(real_png_bytes)
    for pos, mask in flips:
        data[pos % len(data)] ^= mask
    try:
        depth = read_depth_png(_write(tmp_path / "b.png", bytes(data)))
    except InputError:
        return
    assert depth.dtype == np.float32 and depth.ndim == 2 and np.all(np.isfinite(depth))


def test_encode_rounding_and_clipping():
    depth = np.array([[0.0, 1 / 256, 0.5 / 256 * 0.99, 1.0],
                      [255.996, 300.0, -1.0, np.inf],
                      [-np.inf, 10.0 + 0.49 / 256, 10.0 + 0.51 / 256, 1e-9]], np.float32)
    got = encode_depth_uint16(depth)
    want = np.array([[0, 1, 0, 256],
                     [65535, 65535, 0, 65535],
                     [0, 2560, 2561, 0]], np.uint16)
    np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("dtype", [np.float32, np.float64, np.int32])
def test_encode_in_range_fast_path_equals_the_clip_formula(dtype, caplog):
    # Every value in range takes the two-reduction path; the oracle is the documented formula in float64.
    rng = np.random.default_rng(7)
    depth = rng.uniform(0.0, 255.99, (37, 53))
    depth[rng.random(depth.shape) < 0.3] = 0.0
    depth.flat[:6] = [-0.0, 0.5 / 256, 1.5 / 256, 65535.49 / 256, 255.5, -0.49 / 256]  # halves: to even
    depth = depth.astype(dtype) if dtype != np.int32 else np.floor(np.abs(depth)).astype(dtype)
    oracle = np.clip(np.rint(depth.astype(np.float64) * 256.0), 0, 65535).astype(np.uint16)
    with caplog.at_level("WARNING", logger="jaxdepth"):
        got = encode_depth_uint16(depth)
    assert got.dtype == np.uint16 and not caplog.records  # nothing clipped: no warning
    np.testing.assert_array_equal(got, oracle)
    over = depth.astype(np.float64)
    over[0, 0] = 65535.5 / 256       # rounds to 65536: the checked path, clipped and logged
    with caplog.at_level("WARNING", logger="jaxdepth"):
        got = encode_depth_uint16(over)
    assert got[0, 0] == 65535 and "clipped 0 negative depths to 0 (empty) and 1 depths" in caplog.text
    np.testing.assert_array_equal(got.ravel()[1:], oracle.ravel()[1:])


def test_encode_rejects_nan_and_bad_shapes():
    with pytest.raises(ValueError, match=r"'depth_m' expected no NaN .*got 1 NaN pixels"):
        encode_depth_uint16(np.array([[1.0, np.nan]], np.float32))
    with pytest.raises(ValueError, match=r"'depth_m' expected a non-empty \(H, W\) array, got shape \(3,\)"):
        encode_depth_uint16(np.zeros(3))
    with pytest.raises(ValueError, match=r"expected real numbers"):
        encode_depth_uint16(np.zeros((2, 2), complex))


@settings(deadline=None, max_examples=30)
@given(h=st.integers(1, 20), w=st.integers(1, 20), seed=st.integers(0, 2**32 - 1),
       empty_share=st.floats(0.0, 1.0))
def test_round_trip_within_half_step(tmp_path_factory, h, w, seed, empty_share):
    rng = np.random.default_rng(seed)
    depth = rng.uniform(0.01, 255.9, (h, w)).astype(np.float32)
    depth[rng.random((h, w)) < empty_share] = 0.0
    before = depth.copy()
    path = tmp_path_factory.mktemp("png") / "d.png"
    write_depth_png(path, depth)
    np.testing.assert_array_equal(depth, before)  # input untouched
    back = read_depth_png(path)
    assert back.dtype == np.float32 and back.shape == (h, w)
    assert np.max(np.abs(back - depth)) <= 1 / 512 + 1e-4
    np.testing.assert_array_equal(back == 0, depth == 0)  # 0 stays 0, nothing >= 1/256 m vanishes
    raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)  # independent decoder path
    np.testing.assert_array_equal(raw, np.clip(np.rint(depth.astype(np.float64) * 256), 0, 65535))


def test_real_file_round_trip_is_exact_and_deterministic(tmp_path, kitti_frame):
    depth = read_depth_png(kitti_frame / "groundtruth_image_02.png")
    a, b = tmp_path / "a.png", tmp_path / "b.png"
    write_depth_png(a, depth)
    write_depth_png(b, depth.copy())
    assert a.read_bytes() == b.read_bytes()
    np.testing.assert_array_equal(read_depth_png(a), depth)


def test_write_overwrite_flag(tmp_path):
    path = tmp_path / "d.png"
    write_depth_png(path, np.ones((2, 2), np.float32))
    with pytest.raises(OutputError, match="already exists"):
        write_depth_png(path, np.zeros((2, 2), np.float32), overwrite=False)
    np.testing.assert_array_equal(read_depth_png(path), np.ones((2, 2)))
    write_depth_png(path, np.zeros((2, 2), np.float32))
    np.testing.assert_array_equal(read_depth_png(path), np.zeros((2, 2)))


def _dense_kitti_like(kitti_frame):
    """A dense depth map with real structure: the ground truth with its holes filled row-wise."""
    gt = read_depth_png(kitti_frame / "groundtruth_image_02.png")
    filled = np.maximum.accumulate(gt, axis=1)
    return filled.astype(np.float32)


def test_compression_levels_store_the_same_values_and_bytes_are_deterministic(tmp_path, kitti_frame):
    """Issue 14: --png-compression changes size and time only; OpenCV (an independent decoder) and
    our reader get the same uint16 values at every level, and a level always gives the same bytes."""
    depth = _dense_kitti_like(kitti_frame)
    want = encode_depth_uint16(depth)
    sizes = {}
    for level in range(10):
        a, b = tmp_path / f"a{level}.png", tmp_path / f"b{level}.png"
        write_depth_png(a, depth, compression=level)
        write_depth_png(b, depth.copy(), compression=level)
        assert a.read_bytes() == b.read_bytes()
        np.testing.assert_array_equal(cv2.imread(str(a), cv2.IMREAD_UNCHANGED), want)
        np.testing.assert_array_equal(read_depth_png(a), read_depth_png(tmp_path / "a0.png"))
        sizes[level] = a.stat().st_size
    assert sizes[0] > 2 * sizes[1] and sizes[9] <= sizes[1]
    # the default is a valid level and equals passing it explicitly
    write_depth_png(tmp_path / "d.png", depth)
    from jaxdepth.io.depth_png import DEFAULT_PNG_COMPRESSION
    assert (tmp_path / "d.png").read_bytes() == (tmp_path / f"a{DEFAULT_PNG_COMPRESSION}.png").read_bytes()


@pytest.mark.parametrize("shape", [(1, 1), (1, 7), (5, 1), (3, 4)])
def test_encode_depth_png_matches_opencv_on_small_and_extreme_values(shape):
    from jaxdepth.io import encode_depth_png
    rng = np.random.default_rng(sum(shape))
    array = rng.integers(0, 65536, shape).astype(np.uint16)
    array.flat[0] = 65535
    data = encode_depth_png(array, compression=6)
    np.testing.assert_array_equal(cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED), array)


def test_encode_depth_png_rejects_bad_levels_and_arrays(tmp_path):
    from jaxdepth.io import encode_depth_png
    ok = np.zeros((2, 2), np.uint16)
    for level in (-1, 10, 1.5, True):
        with pytest.raises(ValueError, match=f"'compression' expected an integer 0-9, got {level!r}"):
            encode_depth_png(ok, compression=level)
    with pytest.raises(ValueError, match="uint16"):
        encode_depth_png(np.zeros((2, 2), np.float32))
    with pytest.raises(OutputError, match="ending in .png"):
        write_depth_png(tmp_path / "x.jpg", np.zeros((2, 2), np.float32))


# --- the PNG encoder: ISA-L (the optional extra fast-png) or Python's zlib (issue 38) ---------------

def _idat(data: bytes) -> bytes:
    """The IDAT payload of a one-IDAT PNG (as encode_depth_png writes), its CRC checked."""
    length = struct.unpack(">I", data[33:37])[0]
    assert data[37:41] == b"IDAT"
    payload = data[41:41 + length]
    assert struct.unpack(">I", data[41 + length:45 + length])[0] == zlib.crc32(payload, zlib.crc32(b"IDAT"))
    return payload


def _force_zlib(monkeypatch):
    from jaxdepth.io import depth_png
    monkeypatch.setattr(depth_png, "_isal_zlib", None)


_ENCODER_ARRAYS = [
    np.random.default_rng(0).integers(0, 65536, (37, 53), dtype=np.uint16),  # random, odd sizes
    np.zeros((5, 7), np.uint16), np.full((5, 7), 65535, np.uint16),  # the edge values
    np.array([[0, 65535, 1, 65534, 256, 255]], np.uint16),  # one row
    np.array([[0], [65535], [1], [300], [65535]], np.uint16),  # one column
    np.where(np.random.default_rng(1).random((64, 99)) < 0.06,  # sparse LiDAR-like
             np.random.default_rng(2).integers(1, 65536, (64, 99)), 0).astype(np.uint16),
]


@pytest.mark.parametrize("index", range(len(_ENCODER_ARRAYS)))
@pytest.mark.parametrize("level", [1, 2, 3])
def test_both_encoders_decode_to_the_same_array_and_repeat_their_bytes(monkeypatch, index, level):
    """ISA-L's bytes differ from zlib's, their values never: OpenCV (an independent decoder) reads both
    to the input array; each encoder gives the same bytes twice."""
    from jaxdepth.io import encode_depth_png
    array = _ENCODER_ARRAYS[index]
    first = encode_depth_png(array, compression=level)
    assert encode_depth_png(array.copy(), compression=level) == first
    with monkeypatch.context() as m:
        _force_zlib(m)
        plain = encode_depth_png(array, compression=level)
        assert encode_depth_png(array.copy(), compression=level) == plain
        assert zlib.decompressobj().decompress(_idat(plain)) == zlib.decompress(_idat(first))
    for data in (first, plain):
        decoded = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
        assert decoded.dtype == np.uint16
        np.testing.assert_array_equal(decoded, array)


def test_png_encoder_names_the_library_that_writes(monkeypatch):
    from jaxdepth.io import depth_png, png_encoder
    try:
        from isal import isal_zlib
    except ImportError:
        isal_zlib = None
    if isal_zlib is None:
        assert png_encoder() == f"zlib {zlib.ZLIB_RUNTIME_VERSION}"
    else:
        import isal
        assert png_encoder() == f"isal {isal.__version__}"
        array = _ENCODER_ARRAYS[0]
        assert _idat(depth_png.encode_depth_png(array, compression=1)) == isal_zlib.compress(_filtered_rows(array), 1)
    _force_zlib(monkeypatch)
    assert png_encoder() == f"zlib {zlib.ZLIB_RUNTIME_VERSION}"


def _filtered_rows(array: np.ndarray) -> np.ndarray:
    """The PNG rows with filter Up, written independently of the library (NumPy int arithmetic)."""
    be = array.astype(">u2").view(np.uint8).reshape(array.shape[0], -1).astype(np.int64)
    up = np.vstack([be[:1], (be[1:] - be[:-1]) % 256])
    return np.hstack([np.full((array.shape[0], 1), 2), up]).astype(np.uint8)


@pytest.mark.parametrize("level", [0, 4, 5, 6, 7, 8, 9])
def test_levels_0_and_4_to_9_are_zlib_s_bytes(monkeypatch, level):
    """ISA-L writes levels 1-3 only (its level 0 is not "stored"): the other levels are Python's zlib,
    installed extra or not."""
    from jaxdepth.io import encode_depth_png
    array = _ENCODER_ARRAYS[5]
    expected = zlib.compress(_filtered_rows(array), level)
    assert _idat(encode_depth_png(array, compression=level)) == expected
    _force_zlib(monkeypatch)
    assert _idat(encode_depth_png(array, compression=level)) == expected


def test_the_run_record_names_the_png_encoder_and_a_change_of_encoder_resumes(monkeypatch, tmp_path):
    """The encoder is recorded, but is neither a setting nor the output version: the values are the same."""
    from jaxdepth.batch.run_record import claim_folder, make_record
    from jaxdepth.io import png_encoder
    record = make_record({"method": "sgm"}, inputs=[], command=["jaxdepth", "complete"])
    assert record["png_encoder"] == png_encoder()
    claim_folder(tmp_path, record, overwrite=False)
    write_depth_png(tmp_path / "a.png", np.ones((4, 4)))
    _force_zlib(monkeypatch)
    other = make_record({"method": "sgm"}, inputs=[], command=["jaxdepth", "complete"])
    assert other["png_encoder"].startswith("zlib ")
    assert claim_folder(tmp_path, other, overwrite=False) == []  # resumed: same settings, output version
    assert (tmp_path / "a.png").exists()
