"""benchmarks/accuracy_twins.py at a tiny scale: structure, scores against NumPy, the agreement table."""

import numpy as np
import pytest

from benchmarks import accuracy_twins as bench


def _numpy_rmse_mae(pred, truth):
    m = truth > 0
    err = (pred[m].astype(np.float64) - truth[m]) * 1000.0
    return np.sqrt(np.mean(err ** 2)), np.mean(np.abs(err))


@pytest.mark.slow  # a whole pipeline program of its own (docs/testing.md)
def test_one_twin_case_structure_and_scores(tmp_path):
    from jaxdepth.research.twins import make_twin, write_twin
    twin = make_twin("rosette", sweeps=1, seed=0, scale=0.1)
    paths = write_twin(twin, tmp_path)
    inp = bench.read_user_input(paths["sweeps"][0], paths["rig"])
    assert inp.multi == bool(twin.rig.lidars)     # one point file: multi-source exactly when the rig has lidars
    # the sizes a merge gives an old case without building its twin are make_twin's
    assert bench.twin_camera_sizes("rosette", 0.1) == [[c.width, c.height] for c in twin.rig.cameras]
    exact = bench.exact_truth(twin, inp.rig)
    hidden, targets, full = bench.hold_out(inp, 0)
    truths, stats = bench.protocol_truths(exact, targets, full, bench.cover_half_height(inp))
    preds = bench.predictions(inp, ~hidden, bench.SGMConfig())
    assert set(preds) == set(bench.METHODS)
    for name in bench.METHODS:
        assert [p.shape for p in preds[name]] == [e.shape for e in exact]
    # the held-out draw is hidden-eval's: about 20 % of the reference points at >= 1 m
    assert 0.15 < hidden.sum() / len(hidden) < 0.25
    assert stats["targets"] == sum(int((t > 0).sum()) for t in targets) > 0
    # exact depth at the held-out pixels: exactly the targets' pixels (where the exact depth has a hit)
    for t, e, x in zip(targets, exact, truths["exact_held_out"]):
        np.testing.assert_array_equal(x > 0, (t > 0) & (e > 0))
    # uncovered targets are a subset of all targets, values unchanged
    for t, u in zip(targets, truths["hidden_uncovered"]):
        assert np.all((u == 0) | (u == t))
    # the devkit score of a fully dense prediction equals a NumPy RMSE / MAE on the same pixels
    for name in ("nearest", "nearest_l2"):
        for p in preds[name]:
            assert np.all(p > 0)
        for proto in ("exact_dense", "hidden_all"):
            got = bench.score(preds[name], truths[proto])
            for cam, (p, t) in zip(got["per_camera"], zip(preds[name], truths[proto])):
                rmse, mae = _numpy_rmse_mae(p, t)
                np.testing.assert_allclose([cam["rmse"], cam["mae"]], [rmse, mae], rtol=1e-4)
    # scores of this draw, as run_case stores them: agreement of a protocol with itself is 100 %
    case = {"rig": "rosette", "held_out": [{"scores": {p: {m: bench.score(preds[m], truths[p])
                                                          for m in bench.METHODS} for p in bench.PROTOCOLS}}]}
    table = bench.agreement([case])
    for metric in bench.KEYS:
        row = table[metric]["exact_dense"]["overall"]
        assert row["agree_pct"] == 100.0
        # one sweep: the free-space rules have nothing to judge (sgm_no_free_space == sgm), a tie left out
        assert 0 < row["pairs"] < len(bench.METHODS) * (len(bench.METHODS) - 1) // 2


def _case(rig, scores_by_protocol):
    return {"rig": rig, "held_out": [{"scores": {p: {m: {"rmse": v, "mae": v} for m, v in zip(bench.METHODS, vals)}
                                                 for p, vals in scores_by_protocol.items()}}]}


def test_agreement_counts_pairs_against_an_analytic_answer():
    n = len(bench.METHODS)
    up = list(range(1, n + 1))
    swapped = up[:]
    swapped[0], swapped[1] = swapped[1], swapped[0]     # one pair of n (n - 1) / 2 in the other order
    tied = [1.0] * n
    case = _case("a", {"exact_dense": up, "exact_held_out": up, "hidden_all": up[::-1], "hidden_uncovered": swapped})
    other = _case("b", {"exact_dense": up, "exact_held_out": tied, "hidden_all": up, "hidden_uncovered": up})
    table = bench.agreement([case, other])
    pairs = n * (n - 1) // 2
    for metric in bench.KEYS:
        t = table[metric]
        assert t["hidden_all"]["a"] == {"agree_pct": 0.0, "pairs": pairs}
        assert t["hidden_uncovered"]["a"]["agree_pct"] == pytest.approx(100.0 * (pairs - 1) / pairs)
        assert t["exact_held_out"]["b"]["agree_pct"] == 0.0              # a tie does not rank a pair
        assert t["hidden_all"]["overall"] == {"agree_pct": 50.0, "pairs": 2 * pairs}
    # pairs tied under the exact dense depth are left out
    flat = _case("c", {p: [1.0] * n for p in bench.PROTOCOLS})
    assert bench.agreement([flat]) == {"rmse": {}, "mae": {}}


def _scaled_case(rig, sweeps, seed, value, scale=None, sizes=((8, 4),)):
    case = {"rig": rig, "sweeps": sweeps, "seed": seed, "held_out": [],
            "full": {m: {"rmse": value, "mae": value} for m in bench.METHODS}}
    if scale is not None:
        case.update(scale=scale, camera_sizes=[list(s) for s in sizes])
    return case


def _part(cases, scale=None, seconds=1.0):
    return {"settings": {"scale": scale}, "cases": cases, "seconds": seconds, "complete": True}


def test_each_twin_runs_at_its_own_scale_unless_overridden():
    assert {bench.rig_scale(r) for r in bench.RIGS} == {1.0}                       # the real camera sizes
    assert {bench.rig_scale(r, 0.5) for r in bench.RIGS} == {0.5}                 # --scale: one for all


def test_merge_mixes_scales_across_twins_and_replaces_a_twin_run_at_another_scale():
    old = _part([_scaled_case("kitti", n, 0, 10.0 + n) for n in (1, 3, 5)]
                + [_scaled_case("av2", n, 0, 20.0 + n) for n in (1, 5)], scale=0.25)   # written before per-twin scales
    new = _part([_scaled_case("kitti", n, 0, 30.0 + n, scale=1.0, sizes=((1242, 375), (1242, 375)))
                 for n in (1, 5)])
    extra = _part([_scaled_case("av2", 5, 0, 99.0, scale=0.25, sizes=((512, 388),))])
    cases, merged_from = bench.merge_parts([old, new, extra], [None, "full-size KITTI", None])
    got = {(c["rig"], c["sweeps"], c["scale"]): c["full"]["sgm"]["rmse"] for c in cases}
    assert [(c["rig"], c["sweeps"]) for c in cases] == [("kitti", 1), ("kitti", 5), ("av2", 1), ("av2", 5)]
    # every KITTI case at 0.25 goes (3 sweeps too: a twin keeps one scale); av2 5 is the later file's
    assert got == {("kitti", 1, 1.0): 31.0, ("kitti", 5, 1.0): 35.0, ("av2", 1, 0.25): 21.0, ("av2", 5, 0.25): 99.0}
    # an old case gets make_twin's camera sizes at its file's scale
    assert [c["camera_sizes"] for c in cases if c["rig"] == "av2"][0] == bench.twin_camera_sizes("av2", 0.25)
    assert [m["cases"] for m in merged_from] == [
        "av2 at camera scale 0.25, sweeps 1, seeds 0, no hold-out",
        "kitti at camera scale 1, sweeps 1 5, seeds 0, no hold-out",
        "av2 at camera scale 0.25, sweeps 5, seeds 0, no hold-out"]
    assert merged_from[1]["note"] == "full-size KITTI" and "note" not in merged_from[0]
    assert bench.scales(cases) == {"kitti": 1.0, "av2": 0.25}
    with pytest.raises(ValueError, match="field 'scale' of the kitti cases"):
        bench.summary(cases + [_scaled_case("kitti", 3, 0, 1.0, scale=0.25)])


def test_tables_state_each_twins_scale():
    cases = ([_scaled_case("kitti", n, 0, 10.0, scale=1.0, sizes=((1242, 375), (1242, 375))) for n in (1, 5)]
             + [_scaled_case("av2", n, 0, 20.0, scale=0.25, sizes=((388, 512), (512, 388), (512, 388)))
                for n in (1, 5)])
    args = type("Args", (), {"rigs": ["kitti", "av2"], "sweeps": [1, 5], "seeds": [0], "hidden_seeds": [],
                             "scale": None})()
    text = bench.markdown(bench.document(cases, args, complete=True))
    rows = [line for line in text.splitlines() if line.startswith("| kitti") or line.startswith("| av2")]
    assert len(rows) == 6                                    # 2 twins x 2 sweep counts, and the targets table
    assert all("| 1 (1242 x 375) |" in r for r in rows if r.startswith("| kitti"))
    assert all("| 0.25 (512 x 388) |" in r for r in rows if r.startswith("| av2"))
