"""Scoring predictions against ground truth with KITTI devkit metrics.

Contract:

* ``PRED_ROOT`` and ``GT_ROOT`` are folders of KITTI depth PNGs (uint16, metres *
  256), flat or nested: both are walked recursively for ``*.png`` (hidden files
  skipped, folder links followed).
* Files are paired by **frame identity** (:func:`frame_identity`), not by file
  name, so a flat folder of ``jaxdepth complete`` outputs (named like the sparse
  input, ``..._velodyne_raw_<frame>_image_02.png``) pairs with the selection
  folder's ``..._groundtruth_depth_<frame>_image_02.png`` or with the KITTI
  ``<drive>/proj_depth/groundtruth/image_02/<frame>.png`` tree.
* Two files of one side with the same identity are an error naming both.
* Ground-truth frames without a prediction are listed (``missing_predictions``)
  and **not scored**: the mean is over the paired frames only (the official
  devkit expects a prediction for every ground-truth file, so a benchmark number
  needs this list empty; we report instead of scoring a made-up prediction). Predictions without ground truth are listed
  (``unmatched_predictions``) and not scored either: the annotated KITTI sets
  leave out frames (e.g. the first and last five of each drive), so a complete
  run over a drive has them. Neither is an error; no pair at all is.
* Per-frame metrics follow the devkit (empty predictions filled by
  ``interpolate_background``; RMSE / MAE in mm over ``gt > 0``, iRMSE / iMAE in
  1/km), and the data-set score is the mean over frames.
"""

from __future__ import annotations

import csv
import io
import logging
import os
import pathlib
import re
from typing import NamedTuple

import numpy as np

from jaxdepth._src.metrics import depth_metrics, mean_metrics
from jaxdepth.io.depth_png import read_depth_png
from jaxdepth.io.errors import InputError

log = logging.getLogger("jaxdepth")

METRIC_KEYS = ("rmse", "mae", "irmse", "imae")
CSV_COLUMNS = ("frame", "rmse_mm", "mae_mm", "irmse_per_km", "imae_per_km", "prediction", "ground_truth")

# Kinds (the <name> of a layout, see frame_identity) that mark a file's role.
GROUND_TRUTH_KINDS = frozenset({"groundtruth", "groundtruth_depth"})
CAMERA_IMAGE_KINDS = frozenset({"image"})  # RGB images of a selection folder: never depth
# jaxdepth complete's extra outputs <stem>_<kind>.png (jaxdepth.batch.extras): never depth predictions
_EXTRA_OUTPUT = re.compile(r"_(preview|validity|seed_distance)\.png$")
_SELECTION_SUBFOLDERS = frozenset({"velodyne_raw", "groundtruth_depth", "image"})

_KITTI_DRIVE = r"\d{4}_\d{2}_\d{2}_drive_\d{4}_sync"
_SELECTION_NAME = re.compile(
    rf"^(?P<drive>{_KITTI_DRIVE})_(?P<kind>\w+?)_(?P<frame>\d{{10}})_(?P<camera>image_0\d)\.png$")
_TREE_CAMERA = re.compile(r"^image_0\d$")
# A role word as a whole '_'-separated token of a file name (not the whole stem).
_ROLE_TOKEN = re.compile(r"(?:^|_)(velodyne_raw|groundtruth_depth|groundtruth)(?=_|\.png$)")
_SHOW = 3  # names shown of an unmatched list


def frame_identity(relpath) -> tuple[str, str | None]:
    """The frame a depth PNG belongs to, from its path relative to the folder walked.

    Args:
      relpath: ``str`` or ``PurePath`` of the PNG relative to PRED_ROOT / GT_ROOT
        (``/``-separated; the KITTI rules look at the last five components only).

    Returns:
      ``(identity, kind)``: ``identity`` is the pairing key (a prediction and a
      ground truth with equal identities are scored together); ``kind`` is the
      layout's ``<name>`` (``velodyne_raw``, ``groundtruth``, ``sgm``, ...) or None.

    Layouts, first match wins (``X`` a camera digit, ``F`` a frame number), except
    that the selection-subfolder and role-word rules apply one after the other:

    =====================  ====================================================  ==================================
    layout                 path                                                  identity (kind)
    =====================  ====================================================  ==================================
    KITTI tree             ``<drive>/proj_depth/<name>/image_0X/<F>.png``        ``<drive>/image_0X/<F>`` (<name>)
    KITTI selection        ``[...]/<drive>_<name>_<F>_image_0X.png``, <drive>    ``<drive>/image_0X/<F>`` (<name>)
                           like ``2011_09_26_drive_0002_sync``, <F> 10 digits
    selection subfolder    ``[...]/<sub>/<file>.png``, <sub> one of              ``[...]/<file>.png`` (<sub>), then:
                           ``velodyne_raw``, ``groundtruth_depth``, ``image``
    role word              ``[...]/<a>_<word>_<b>.png``, <word> one of           ``[...]/<a>_<b>.png`` (<word>)
                           ``velodyne_raw``, ``groundtruth_depth``,
                           ``groundtruth`` (a whole ``_``-separated word, not
                           the whole stem; also at the start or the end)
    anything else          ``[...]/<file>.png``: same names on both sides,       the path itself (None)
                           ``complete-rig``'s ``<camera>.png``
    =====================  ====================================================  ==================================

    So ``2011_09_26_drive_0002_sync_velodyne_raw_0000000005_image_02.png``,
    ``2011_09_26_drive_0002_sync_groundtruth_depth_0000000005_image_02.png`` and
    ``2011_09_26_drive_0002_sync/proj_depth/groundtruth/image_02/0000000005.png``
    all are ``2011_09_26_drive_0002_sync/image_02/0000000005``; ``_image_03`` is
    another frame.
    """
    parts = pathlib.PurePosixPath(pathlib.PurePath(relpath).as_posix()).parts
    name = parts[-1]
    if len(parts) >= 5 and parts[-4] == "proj_depth" and _TREE_CAMERA.match(parts[-2]) and name.endswith(".png"):
        return f"{parts[-5]}/{parts[-2]}/{name[:-4]}", parts[-3]
    m = _SELECTION_NAME.match(name)
    if m:
        return f"{m['drive']}/{m['camera']}/{m['frame']}", m["kind"]
    folders = parts[:-1]
    kind = None
    if folders and folders[-1] in _SELECTION_SUBFOLDERS:
        folders, kind = folders[:-1], folders[-1]
    m = _ROLE_TOKEN.search(name)
    if m and name[:-4] != m[1]:
        end = m.end() + (1 if m.start() == 0 else 0)  # drop one '_' beside the word
        name, kind = name[:m.start()] + name[end:], m[1]
    return "/".join(folders + (name,)), kind


class _Entry(NamedTuple):
    identity: str
    kind: str | None
    rel: str  # path relative to the root, '/'-separated


def _walk_pngs(root: pathlib.Path) -> list:
    """Relative paths ('/'-separated, sorted) of every non-hidden ``*.png`` under ``root``."""
    found, seen = [], set()
    for folder, subfolders, files in os.walk(root, followlinks=True):
        real = os.path.realpath(folder)
        if real in seen:  # a folder link back up the tree
            subfolders[:] = []
            continue
        seen.add(real)
        subfolders[:] = sorted(d for d in subfolders if not d.startswith("."))
        rel_folder = pathlib.PurePath(folder).relative_to(root)
        found += [(rel_folder / f).as_posix() for f in files if f.endswith(".png") and not f.startswith(".")]
    return sorted(found)


def collect_frames(root, *, side: str) -> tuple[dict, list]:
    """The depth PNGs under ``root`` keyed by :func:`frame_identity`.

    Args:
      root: folder, walked recursively.
      side: ``"prediction"`` or ``"ground truth"``. Camera images (kind ``image``)
        and ``jaxdepth complete``'s extra outputs (``*_preview.png``,
        ``*_validity.png``, ``*_seed_distance.png``) are skipped on both sides. On the ground-truth side, when any file is
        marked as ground truth (kind ``groundtruth`` / ``groundtruth_depth``), only
        those are read (a merged KITTI tree or a whole selection folder holds the
        LiDAR input beside them); on the prediction side such files are skipped
        unless nothing else is there.

    Returns:
      ``({identity: relative path}, [relative paths skipped by the rules above])``.

    Raises:
      InputError: ``root`` is not a folder, or two files share an identity.
    """
    root = pathlib.Path(root)
    if not root.is_dir():
        raise InputError(f"{root}: folder not found (expected a folder of {side} depth PNGs)")
    entries = [_Entry(*frame_identity(rel), rel) for rel in _walk_pngs(root)]
    kept = [e for e in entries if e.kind not in CAMERA_IMAGE_KINDS and not _EXTRA_OUTPUT.search(e.rel)]
    marked = [e for e in kept if e.kind in GROUND_TRUTH_KINDS]
    if side == "ground truth":
        kept = marked or kept
    elif side == "prediction":
        kept = [e for e in kept if e.kind not in GROUND_TRUTH_KINDS] or kept
    else:
        raise ValueError(f"collect_frames: field 'side' expected 'prediction' or 'ground truth', got {side!r}")
    frames = {}
    for e in kept:
        if e.identity in frames:
            raise InputError(f"{root}: {side} files '{frames[e.identity]}' and '{e.rel}' are the same frame "
                             f"'{e.identity}'; expected one {side} per frame (pass a folder that holds one set)")
        frames[e.identity] = e.rel
    kept_rel = set(frames.values())
    return frames, [e.rel for e in entries if e.rel not in kept_rel]


def evaluate_pairs(pairs) -> dict:
    """``pairs``: iterable of (name, pred (H, W), gt (H, W)) metres. Returns {'mean', 'per_frame'}."""
    per_frame = {}
    for name, pred, gt in pairs:
        if pred.shape != gt.shape:
            raise InputError(f"{name}: prediction shape {pred.shape} expected to equal ground truth {gt.shape}")
        m = depth_metrics(np.asarray(pred, np.float32), np.asarray(gt, np.float32))
        per_frame[name] = {k: float(m[k]) for k in METRIC_KEYS}
    if not per_frame:
        raise InputError("no frames to evaluate")
    mean = mean_metrics(list(per_frame.values()))
    return {"mean": {k: float(mean[k]) for k in METRIC_KEYS}, "per_frame": per_frame}


def _examples(names) -> str:
    shown = ", ".join(names[:_SHOW])
    return shown + (", ..." if len(names) > _SHOW else "")


#: A completion covers nearly every ground-truth pixel; below this share the sides look swapped
#: (measured on the shared KITTI frame: a completion 100 %, velodyne_raw 21 %, a swapped ground truth 19 %).
MIN_GT_COVERAGE = 0.5


def _looks_like(density: float) -> str:
    if density >= 0.9:
        return "dense, like a completion"
    if density >= 0.1:
        return "semi-dense, like KITTI ground truth"
    return "sparse, like LiDAR input"


def side_counts(pred: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """(4,) int64 pixel counts of one pair for :func:`side_problem`: ground-truth pixels, those where
    the prediction is non-zero, non-zero predictions, all pixels."""
    scored = gt > 0
    return np.array([np.count_nonzero(scored), np.count_nonzero(pred[scored] > 0), np.count_nonzero(pred > 0),
                     pred.size], np.int64)


def side_problem(counts: np.ndarray) -> str | None:
    """Why the pairs of summed :func:`side_counts` look like the wrong sides (None: completions
    scored against ground truth).

    A completion is non-zero at nearly every pixel where ground truth is; ground truth
    (~19 % of a KITTI image) or LiDAR input (~4 %) given as the prediction covers a
    fraction. Over all pairs, under :data:`MIN_GT_COVERAGE` is refused; the message says
    what each side looks like.
    """
    scored, covered, pred_nonzero, total = (int(c) for c in counts)
    if scored == 0:
        return None
    coverage = covered / scored
    if coverage >= MIN_GT_COVERAGE:
        return None
    dp, dg = pred_nonzero / total, scored / total
    if dg >= 0.9:
        hint = "the ground-truth side looks like completions: were the two folders swapped (PRED_ROOT first)?"
    elif dp < 0.1:
        hint = "the predictions look like LiDAR input (velodyne_raw), not completions"
    else:
        hint = "expected completions as the predictions"
    return (f"the predictions are non-zero at only {100 * coverage:.0f} % of the ground-truth pixels "
            f"(predictions: {100 * dp:.1f} % of the pixels, {_looks_like(dp)}; ground truth: {100 * dg:.1f} %, "
            f"{_looks_like(dg)}); {hint}")


def _read_pair(pred_root: pathlib.Path, gt_root: pathlib.Path, identity: str, pair: dict, force: bool = False):
    from jaxdepth.io.plausibility import check_depth_scale
    pred_path, gt_path = pred_root / pair["prediction"], gt_root / pair["ground_truth"]
    pred, gt = read_depth_png(pred_path), read_depth_png(gt_path)
    if pred.shape != gt.shape:
        raise InputError(f"{pred_path}: prediction shape {pred.shape} expected to equal the shape {gt.shape} "
                         f"of its ground truth {gt_path} (frame '{identity}')")
    check_depth_scale(gt, path=gt_path, role="ground truth", force=force)
    check_depth_scale(pred, path=pred_path, role="prediction", force=force)
    return identity, pred, gt


def evaluate_folders(pred_dir, gt_dir, *, force: bool = False) -> dict:
    """KITTI devkit metrics of every prediction PNG under ``pred_dir`` paired with a
    ground-truth PNG under ``gt_dir`` by :func:`frame_identity`.

    Returns:
      dict (JSON-ready): ``mean`` and ``per_frame[identity]`` (``rmse``, ``mae`` in
      mm, ``irmse``, ``imae`` in 1/km), ``pairs[identity]`` (``prediction``,
      ``ground_truth``: paths relative to ``prediction_root`` / ``ground_truth_root``),
      ``missing_predictions`` / ``unmatched_predictions`` (relative paths of the
      ground truth without prediction / the predictions without ground truth, not
      scored) and ``ignored`` (relative paths skipped by :func:`collect_frames`).
      Frames are in identity order.

    Raises:
      InputError: a folder is missing or holds no PNG, no frame pairs, two files of
        one side are the same frame, a PNG is unreadable, or a pair differs in shape;
        unless ``force`` (then logged): a PNG not in metres x 256
        (:func:`jaxdepth.io.plausibility.check_depth_scale`), or a prediction that
        cover under half of the ground-truth pixels over all pairs (:func:`side_problem`:
        swapped folders, LiDAR input given as the predictions).
    """
    pred_dir, gt_dir = pathlib.Path(pred_dir), pathlib.Path(gt_dir)
    preds, pred_ignored = collect_frames(pred_dir, side="prediction")
    gts, gt_ignored = collect_frames(gt_dir, side="ground truth")
    if not preds:
        raise InputError(f"{pred_dir}: no prediction PNG found (searched every subfolder)")
    if not gts:
        raise InputError(f"{gt_dir}: no ground-truth PNG found (searched every subfolder)")
    names = sorted(set(preds) & set(gts))
    if not names:
        raise InputError(
            f"{pred_dir}: no prediction PNG has a ground-truth PNG of the same frame in {gt_dir} "
            f"({len(preds)} predictions, e.g. {_examples(sorted(preds.values()))}; "
            f"{len(gts)} ground truths, e.g. {_examples(sorted(gts.values()))})")
    pairs = {n: {"prediction": preds[n], "ground_truth": gts[n]} for n in names}
    counts = np.zeros(4, np.int64)

    def read_all():
        for n in names:
            identity, pred, gt = _read_pair(pred_dir, gt_dir, n, pairs[n], force)
            counts[:] += side_counts(pred, gt)
            yield identity, pred, gt

    table = evaluate_pairs(read_all())
    problem = side_problem(counts)
    if problem is not None:
        if not force:
            raise InputError(f"{pred_dir}: {problem}; --force scores them anyway")
        log.warning("%s: --force: scoring although %s", pred_dir, problem)
    table.update(
        prediction_root=str(pred_dir), ground_truth_root=str(gt_dir), pairs=pairs,
        missing_predictions=sorted(gts[n] for n in set(gts) - set(preds)),
        unmatched_predictions=sorted(preds[n] for n in set(preds) - set(gts)),
        ignored={"prediction": pred_ignored, "ground_truth": gt_ignored})
    return table


def _describe_ignored(files) -> str:
    """What ignored files are, by kind (relative paths): colour previews, validity masks, camera images..."""
    kinds = []
    texts = {"preview": "colour previews (_preview.png)", "validity": "validity masks (_validity.png)",
             "seed_distance": "seed-distance images (_seed_distance.png)"}
    for kind, text in texts.items():
        if any(str(f).endswith(f"_{kind}.png") for f in files):
            kinds.append(text)
    found = {frame_identity(f)[1] for f in files if not _EXTRA_OUTPUT.search(str(f))}
    if found & CAMERA_IMAGE_KINDS:
        kinds.append("camera images")
    if "velodyne_raw" in found:
        kinds.append("LiDAR input (velodyne_raw)")
    if found & GROUND_TRUTH_KINDS:
        kinds.append("ground truth")
    if found - CAMERA_IMAGE_KINDS - GROUND_TRUTH_KINDS - {"velodyne_raw"}:
        kinds.append("other depth PNGs")
    return ", ".join(kinds)


def format_table(table: dict) -> list:
    """Printable lines: one per frame (full identity; the column as wide as the
    longest), the mean, then warnings naming the unscored files (first three, joined
    to their root)."""
    count = len(table["per_frame"])
    mean_label = f"mean ({count} frames)"
    width = max([len("frame"), len(mean_label)] + [len(n) for n in table["per_frame"]]) + 2
    lines = [f"{'frame':{width}s}{'RMSE mm':>10s}{'MAE mm':>10s}{'iRMSE 1/km':>12s}{'iMAE 1/km':>11s}"]
    rows = list(table["per_frame"].items()) + [(mean_label, table["mean"])]
    for name, m in rows:
        lines.append(f"{name:{width}s}{m['rmse']:10.1f}{m['mae']:10.1f}{m['irmse']:12.2f}{m['imae']:11.2f}")
    roots = {side: pathlib.Path(table.get(f"{side}_root", "")) for side in ("prediction", "ground_truth")}
    unmatched = [str(roots["prediction"] / f) for f in table.get("unmatched_predictions") or []]
    if unmatched:
        lines.append(f"warning: {len(unmatched)} predictions have no ground truth (not scored): {_examples(unmatched)}")
    for side, files in sorted((table.get("ignored") or {}).items()):
        if files:
            what = _describe_ignored(files)
            files = [str(roots[side] / f) for f in files]
            lines.append(f"note: {len(files)} {side.replace('_', ' ')} files ignored ({what}): {_examples(files)}")
    missing = [str(roots["ground_truth"] / f) for f in table.get("missing_predictions") or []]
    if missing:
        lines.append(f"warning: {len(missing)} ground-truth frames have no prediction (not scored, not in the "
                     f"mean): {_examples(missing)}")
    return lines


def format_csv(table: dict) -> str:
    """Per-frame CSV text: ``frame`` (identity), ``rmse_mm``, ``mae_mm``,
    ``irmse_per_km``, ``imae_per_km`` (shortest round-trip floats, ``nan`` for a
    frame without ground-truth pixels), ``prediction`` and ``ground_truth`` (the
    paired files, joined to the roots as given). Rows in identity order; ``\\n``
    line ends."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(CSV_COLUMNS)
    pred_root = pathlib.Path(table["prediction_root"])
    gt_root = pathlib.Path(table["ground_truth_root"])
    for name, m in table["per_frame"].items():
        pair = table["pairs"][name]
        writer.writerow([name] + [repr(float(m[k])) for k in METRIC_KEYS]
                        + [str(pred_root / pair["prediction"]), str(gt_root / pair["ground_truth"])])
    return out.getvalue()


def write_table(table: dict, *, json_path=None, csv_path=None) -> None:
    """Writes :func:`evaluate_folders`' table atomically: the whole table as JSON (sorted keys,
    indent 2) to ``json_path`` and :func:`format_csv` to ``csv_path`` (None: not written)."""
    import json

    from jaxdepth.io.atomic import atomic_write_bytes
    if json_path:
        atomic_write_bytes(pathlib.Path(json_path), json.dumps(table, indent=2, sort_keys=True).encode())
    if csv_path:
        atomic_write_bytes(pathlib.Path(csv_path), format_csv(table).encode())
