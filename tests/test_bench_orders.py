"""The frame benchmarks' call orders (``benchmarks._common.balanced_orders`` / ``order_effects``).

Oracles: counting by brute force over the orders (every permutation once per block, each arm in each
place and after each other arm equally often), a second call with the same seed, and hand-made timings.
"""

import collections
import itertools

import pytest

from benchmarks._common import balanced_orders, order_effects, rotated_orders


@pytest.mark.parametrize("names", [("a", "b"), ("this", "checkout", "ip_basic")])
def test_every_block_holds_every_permutation_once(names):
    k = len(list(itertools.permutations(names)))
    orders = balanced_orders(names, 5 * k, seed=3)
    assert len(orders) == 5 * k
    for b in range(5):
        assert sorted(orders[b * k:(b + 1) * k]) == sorted(itertools.permutations(names))
    place = collections.Counter((n, i) for order in orders for i, n in enumerate(order))
    assert set(place.values()) == {5 * k // len(names)}
    before = collections.Counter((order[i - 1], order[i]) for order in orders for i in range(1, len(order)))
    pairs = [(a, b) for a in names for b in names if a != b]
    assert sorted(before) == sorted(pairs) and len(set(before[p] for p in pairs)) == 1


def test_same_seed_same_orders_and_a_cut_is_a_prefix():
    names = ("x", "y", "z")
    assert balanced_orders(names, 20, seed=7) == balanced_orders(names, 20, seed=7)
    assert balanced_orders(names, 20, seed=7)[:9] == balanced_orders(names, 9, seed=7)
    assert any(balanced_orders(names, 60, seed=s) != balanced_orders(names, 60, seed=0) for s in (1, 2, 3))


def test_order_effects_groups_by_place_and_predecessor():
    calls = [("a", 0, 0.001), ("b", 1, 0.004), ("b", 0, 0.002), ("a", 1, 0.005), ("a", 0, 0.003)]
    got = order_effects(calls, ("a", "b"))
    assert got["by_place"]["a"] == {"0": {"median_ms": pytest.approx(2.0), "calls": 2},
                                    "1": {"median_ms": pytest.approx(5.0), "calls": 1}}
    assert got["after"]["a"] == {"none": {"median_ms": pytest.approx(1.0), "calls": 1},
                                 "b": {"median_ms": pytest.approx(5.0), "calls": 1},
                                 "a": {"median_ms": pytest.approx(3.0), "calls": 1}}
    assert got["after"]["b"] == {"a": {"median_ms": pytest.approx(4.0), "calls": 1},
                                 "b": {"median_ms": pytest.approx(2.0), "calls": 1}}


def test_rotated_orders_move_each_arm_one_place_a_round():
    orders = rotated_orders(("a", "b", "c"), 7)
    assert orders[:4] == [("a", "b", "c"), ("b", "c", "a"), ("c", "a", "b"), ("a", "b", "c")]
    assert all(sorted(o) == ["a", "b", "c"] for o in orders)
