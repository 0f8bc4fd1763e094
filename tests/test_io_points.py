"""Point-file reader and bucket padding."""

from __future__ import annotations

import io
import zipfile

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from jaxdepth._src.geometry import project_to_image
from jaxdepth._src.presets import KITTI_K_CAM2, KITTI_T_CAM2_LIDAR
from jaxdepth.io import InputError, MIN_BUCKET, bucket_size, pad_points, read_points

_HYP = settings(deadline=None, max_examples=30, suppress_health_check=[HealthCheck.function_scoped_fixture])


def test_kitti_bin_matches_fromfile(kitti_frame):
    path = kitti_frame / "lidar_data.bin"
    points, extra = read_points(path)
    oracle = np.fromfile(path, dtype=np.float32).reshape(-1, 4)
    assert points.shape == (121948, 3) and extra.shape == (121948, 1)  # data README
    assert points.dtype == np.float32 and extra.dtype == np.float32
    np.testing.assert_array_equal(points, oracle[:, :3])
    np.testing.assert_array_equal(extra, oracle[:, 3:])
    assert points.flags.c_contiguous


def test_nuscenes_bin_five_columns(nuscenes_sample, tmp_path):
    path = next(nuscenes_sample.glob("*LIDAR_TOP*.pcd.bin"))
    points, extra = read_points(path, columns=5)
    assert points.shape == (34688, 3) and extra.shape == (34688, 2)
    ring = extra[:, 1]
    assert set(np.unique(ring).astype(int)) <= set(range(32)) and np.all(ring == np.round(ring))
    # The same file read with the KITTI default has 34,688 * 5 / 4 = 43,360 records: whole, but the
    # ring index then lands in the coordinates. A 3-column read must fail (34,688 * 5 % 3 != 0).
    with pytest.raises(InputError, match=r"not a whole number of 3-value float32 records"):
        read_points(path, columns=3)
    # the default for a *.pcd.bin is nuScenes' 5 columns, for any other .bin KITTI's 4
    default, extra5 = read_points(path)
    np.testing.assert_array_equal(default, points)
    np.testing.assert_array_equal(extra5, extra)
    plain = tmp_path / "renamed.bin"
    np.fromfile(path, np.float32)[:34680 * 5].tofile(plain)   # a whole number of 4- and of 5-value records
    assert read_points(plain, force=True)[1].shape[1] == 1


def test_bin_size_errors(tmp_path):
    path = tmp_path / "scan.bin"
    path.write_bytes(np.arange(10, dtype=np.float32).tobytes())  # 40 bytes: 2.5 records of 16
    with pytest.raises(InputError, match=r"scan\.bin: size 40 bytes is not a whole number of 4-value float32 "
                                         r"records \(16 bytes each; 2 records \+ 8 bytes\)"):
        read_points(path)
    points, extra = read_points(path, columns=5)
    assert points.shape == (2, 3) and extra.shape == (2, 2)
    path.write_bytes(b"")
    with pytest.raises(InputError, match=r"scan\.bin: file is empty"):
        read_points(path)


def test_missing_suffix_folder(tmp_path):
    with pytest.raises(InputError, match=r"gone\.bin: file not found"):
        read_points(tmp_path / "gone.bin")
    (tmp_path / "a.pcd").write_bytes(b"x")
    with pytest.raises(InputError, match=r"a\.pcd: unsupported suffix '\.pcd', expected \.bin, \.npy or \.npz"):
        read_points(tmp_path / "a.pcd")
    with pytest.raises(InputError, match="is a folder"):
        read_points(tmp_path)
    with pytest.raises(ValueError, match=r"'columns' expected an integer >= 3, got 2"):
        read_points(tmp_path / "a.bin", columns=2)


def test_npy_and_npz(tmp_path):
    rng = np.random.default_rng(1)
    data = rng.normal(size=(50, 4))  # float64: converted to float32
    np.save(tmp_path / "a.npy", data)
    np.savez(tmp_path / "b.npz", points=np.asfortranarray(data), other=np.zeros(3))
    np.savez_compressed(tmp_path / "c.npz", only=data)
    for name in ("a.npy", "b.npz", "c.npz"):
        points, extra = read_points(tmp_path / name)
        np.testing.assert_array_equal(points, data[:, :3].astype(np.float32))
        np.testing.assert_array_equal(extra, data[:, 3:].astype(np.float32))
    np.save(tmp_path / "i.npy", np.arange(12, dtype=np.int16).reshape(4, 3))
    points, extra = read_points(tmp_path / "i.npy", columns=3)
    assert points.dtype == np.float32 and extra.shape == (4, 0)


def _npy_bytes(array: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, array)
    return buf.getvalue()


def _npz_bytes(compressed: bool) -> bytes:
    buf = io.BytesIO()
    (np.savez_compressed if compressed else np.savez)(buf, points=np.arange(40, dtype=np.float32).reshape(10, 4))
    return buf.getvalue()


@pytest.mark.parametrize("make, pattern", [
    (lambda p: np.save(p / "x.npy", np.zeros((5, 3))), r"x\.npy: array expected shape \(N, 4\) for columns=4, got \(5, 3\)"),
    (lambda p: np.save(p / "x.npy", np.zeros((0, 4))), r"x\.npy: array contains no points"),
    (lambda p: np.save(p / "x.npy", np.zeros(8)), r"x\.npy: array expected shape \(N, 4\).*got \(8,\)"),
    (lambda p: np.save(p / "x.npy", np.array([["a"] * 4])), r"x\.npy: array expected a real-valued array, got dtype <U1"),
    (lambda p: np.save(p / "x.npy", np.array([[object()] * 4]), allow_pickle=True),
     r"x\.npy: array expected a real-valued array, got dtype object"),
    (lambda p: np.savez(p / "x.npz", a=np.zeros((2, 4)), b=np.zeros((2, 4))),
     r"x\.npz: expected an array named 'points' or a single array, got keys \['a', 'b'\]"),
    (lambda p: np.savez(p / "x.npz", points=np.zeros((2, 5))), r"x\.npz: array 'points' expected shape \(N, 4\)"),
    (lambda p: np.savez(p / "x.npz"), r"x\.npz: expected an array named 'points' or a single array, got keys \[\]"),
    # np.save / np.savez append their own suffix to a path; write the wrong format under the name.
    (lambda p: (p / "x.npz").write_bytes(_npy_bytes(np.zeros((2, 4)))), r"x\.npz: not a readable \.npz archive"),
    (lambda p: (p / "x.npy").write_bytes(_npz_bytes(False)), r"x\.npy: not a readable \.npy array"),
])
def test_array_file_errors(tmp_path, make, pattern):
    make(tmp_path)
    path = next(tmp_path.glob("x.*"))
    with pytest.raises(InputError, match=pattern):
        read_points(path)


def test_truncated_npy_header_lies(tmp_path):
    path = tmp_path / "big.npy"
    np.save(path, np.zeros((1000, 4), np.float32))
    data = path.read_bytes()
    path.write_bytes(data[:-100])
    with pytest.raises(InputError, match=r"big\.npy: array is truncated: header says shape \(1000, 4\) "
                                         r"\(16000 bytes\), the file holds 15900 bytes"):
        read_points(path)
    # A header that claims a petabyte must fail fast, without allocating it.
    header = data[: data.index(b"\n") + 1].replace(b"(1000, 4)", b"(10**14, 4)".replace(b"10**14", b"%d" % 10**14))
    path.write_bytes(header + b"\0" * 64)
    with pytest.raises(InputError, match="truncated"):
        read_points(path)


def test_non_finite_points_are_returned(tmp_path):
    data = np.array([[1, 2, 3, 0.5], [np.nan, 0, 0, 1], [0, np.inf, 0, 1], [4, 5, 6, np.nan]], np.float32)
    data.tofile(tmp_path / "n.bin")
    points, extra = read_points(tmp_path / "n.bin")
    np.testing.assert_array_equal(points, data[:, :3])
    np.testing.assert_array_equal(extra, data[:, 3:])


# ---------------------------------------------------------------- fuzzing


@_HYP
@given(data=st.binary(max_size=300), suffix=st.sampled_from([".bin", ".npy", ".npz"]),
       columns=st.integers(3, 6))
def test_fuzz_random_bytes(tmp_path, data, suffix, columns):
    path = tmp_path / f"f{suffix}"
    path.write_bytes(data)
    try:
        points, extra = read_points(path, columns=columns)
    except InputError:
        return
    assert points.dtype == np.float32 and points.ndim == 2 and points.shape[1] == 3
    assert extra.shape == (points.shape[0], columns - 3)


@_HYP
@given(kind=st.sampled_from(["npy", "npz", "npzc"]), cut=st.integers(0, 10**6),
       flips=st.lists(st.tuples(st.integers(0, 10**6), st.integers(1, 255)), max_size=3))
def test_fuzz_corrupted_valid_files(tmp_path, kind, cut, flips):
    if kind == "npy":
        data = bytearray(_npy_bytes(np.arange(40, dtype=np.float32).reshape(10, 4)))
    else:
        data = bytearray(_npz_bytes(kind == "npzc"))
    for pos, mask in flips:
        data[pos % len(data)] ^= mask
    data = data[: cut % (len(data) + 1)]
    path = tmp_path / f"c.{kind[:3]}"
    path.write_bytes(bytes(data))
    try:
        points, _ = read_points(path)
    except InputError:
        return
    assert points.dtype == np.float32 and points.shape[1] == 3


def test_regression_unbalanced_npy_header(tmp_path):
    """Found by fuzzing: NumPy's header parser raised tokenize.TokenError, not ValueError."""
    data = _npy_bytes(np.zeros((10, 4), np.float32)).replace(b"(10, 4)", b"(10, 4 ", 1)
    (tmp_path / "h.npy").write_bytes(data)
    with pytest.raises(InputError, match=r"h\.npy: not a readable \.npy array \(TokenError"):
        read_points(tmp_path / "h.npy")


def test_npz_bad_crc_is_input_error(tmp_path):
    data = bytearray(_npz_bytes(False))
    member = zipfile.ZipFile(io.BytesIO(bytes(data))).getinfo("points.npy")
    data[member.header_offset + 30 + len("points.npy") + 130] ^= 0xFF  # inside the array data
    (tmp_path / "crc.npz").write_bytes(bytes(data))
    with pytest.raises(InputError, match=r"crc\.npz: not a readable \.npz archive \(BadZipFile"):
        read_points(tmp_path / "crc.npz")


# ---------------------------------------------------------------- padding


@pytest.mark.parametrize("n, want", [(0, 1024), (1, 1024), (1024, 1024), (1025, 2048), (34688, 65536),
                                     (121948, 131072), (131072, 131072), (131073, 262144)])
def test_bucket_size(n, want):
    assert bucket_size(n) == want
    assert MIN_BUCKET == 1024


@settings(deadline=None, max_examples=40)
@given(n=st.integers(0, 3000), bad_share=st.floats(0, 1), seed=st.integers(0, 2**32 - 1))
def test_pad_points_properties(n, bad_share, seed):
    rng = np.random.default_rng(seed)
    points = rng.normal(scale=20, size=(n, 3))
    bad = rng.random(n) < bad_share
    points[bad, rng.integers(0, 3, bad.sum())] = rng.choice([np.nan, np.inf, -np.inf], bad.sum())
    before = points.copy()
    padded, valid = pad_points(points)
    np.testing.assert_array_equal(points, before)  # input untouched
    size = padded.shape[0]
    assert size == bucket_size(n) and size >= max(n, 1024) and size & (size - 1) == 0
    assert padded.dtype == np.float32 and valid.dtype == np.bool_ and valid.shape == (size,)
    assert np.all(np.isfinite(padded))
    finite = np.all(np.isfinite(points), axis=1)
    np.testing.assert_array_equal(valid[:n], finite)
    assert not valid[n:].any() and not padded[n:].any()
    np.testing.assert_array_equal(padded[:n][finite], points[finite].astype(np.float32))
    assert not padded[:n][~finite].any()


def test_pad_points_explicit_bucket_and_errors():
    padded, valid = pad_points(np.ones((5, 3)), bucket=7)
    assert padded.shape == (7, 3) and valid.sum() == 5
    with pytest.raises(ValueError, match=r"'bucket' expected an integer >= max\(N, 1\) = 5, got 4"):
        pad_points(np.ones((5, 3)), bucket=4)
    with pytest.raises(ValueError, match=r"'points' expected shape \(N, 3\), got \(5, 4\)"):
        pad_points(np.ones((5, 4)))


def test_padding_reuses_one_compilation_and_changes_nothing(kitti_frame):
    """Two sweeps of different lengths in one bucket: one trace; results equal the unpadded projection."""
    points, _ = read_points(kitti_frame / "lidar_data.bin")
    traces = []

    def project(p, v):
        traces.append(p.shape)
        return project_to_image(p, v, KITTI_K_CAM2, KITTI_T_CAM2_LIDAR, height=375, width=1242)

    jitted = jax.jit(project)
    for n in (121948, 100_000):  # both in the 131,072 bucket
        sweep = points[:n].copy()
        sweep[::997] = np.nan  # non-finite returns are masked, not projected
        padded, valid = pad_points(sweep)
        depth, index = jitted(padded, valid)
        finite = np.all(np.isfinite(sweep), axis=1)
        ref, ref_index = project_to_image(jnp.asarray(sweep[finite]), jnp.ones(int(finite.sum()), bool),
                                          KITTI_K_CAM2, KITTI_T_CAM2_LIDAR, height=375, width=1242)
        np.testing.assert_array_equal(np.asarray(depth), np.asarray(ref))
        kept = np.flatnonzero(finite)
        ref_index = np.asarray(ref_index)
        np.testing.assert_array_equal(np.asarray(index), np.where(ref_index >= 0, kept[ref_index], -1))
    assert traces == [(131072, 3)]
