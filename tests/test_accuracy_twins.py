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
