"""SGMConfig refuses bad option values with a message naming the field (no compiled code)."""

from __future__ import annotations

import math

import pytest

from jaxdepth._src.config import SGMConfig

NON_NEGATIVE = ("epsilon_m", "smoothing_sigma_px", "guidance_weight", "guidance_noise_floor")


@pytest.mark.parametrize("field", NON_NEGATIVE)
@pytest.mark.parametrize("value", [-0.5, math.nan])
def test_negative_or_nan_float_option_is_refused(field, value):
    with pytest.raises(ValueError, match=f"field '{field}' expected >= 0"):
        SGMConfig(**{field: value})


@pytest.mark.parametrize("field", NON_NEGATIVE)
def test_zero_is_accepted(field):
    assert getattr(SGMConfig(**{field: 0.0}), field) == 0.0


@pytest.mark.parametrize("changes", [dict(seed_horizontal_cost=0), dict(seed_horizontal_cost=1.5),
                                     dict(seed_horizontal_cost=True),
                                     dict(seed_horizontal_cost=3, distance_metric="l2"),
                                     dict(seed_horizontal_cost=3, guidance_weight=10.0)])
def test_seed_horizontal_cost_is_refused_where_it_has_no_meaning(changes):
    with pytest.raises(ValueError, match="field 'seed_horizontal_cost' expected an integer >= 1"):
        SGMConfig(**changes)


def test_seed_horizontal_cost_cli_flag():
    import argparse

    from jaxdepth.options import add_config_options, config_changes
    p = argparse.ArgumentParser()
    add_config_options(p)
    assert config_changes(p.parse_args(["--seed-horizontal-cost", "3"]))["seed_horizontal_cost"] == 3
    assert "seed_horizontal_cost" not in config_changes(p.parse_args([]))
