"""One metric registry; MetricsConfig keys; aggregation honours (and checks) the configuration; N > 8."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pandas as pd
import pytest
from test_metrics_helpers import constant_speed_plan, inputs, make

import letspi.metrics.aggregate as aggregate_module
from letspi.metrics import (
    METRICS,
    MetricsConfig,
    aggregate_metrics,
    compute_metrics,
    human_future,
    recorded_config,
    reference_markdown,
    render_markdown_table,
)
from letspi.metrics.collision import collisions
from letspi.metrics.pet import pet_grid
from letspi.metrics.registry import CONFIG_COLUMNS, aggregate_keys, computed_metrics
from letspi.metrics.ttc import ttc_1d
from letspi.scenario.build import VehicleSpec
from letspi.scenario.types import concat_batches

# a 25 m/s leader 44.5 m ahead (40 m bumper gap), ego at 30 m/s: gap 40 - 5 t, min TTC 3 s at t = 5 s
CLOSING = [VehicleSpec(x0_m=44.5, speed_mps=25.0)]


def _frame(config: MetricsConfig | None = None) -> pd.DataFrame:
    b = make(CLOSING)
    xy, v = constant_speed_plan(30.0)
    return compute_metrics(b, xy, v, config=config).to_frame()


def test_registry_names_are_unique_and_drive_the_frame() -> None:
    names = [m.name for m in METRICS]
    assert len(names) == len(set(names))
    keys = aggregate_keys()
    assert len(keys) == len(set(keys))
    df = _frame()
    assert list(df.columns) == [m.name for m in computed_metrics()] + list(CONFIG_COLUMNS)
    for m in computed_metrics():
        kind = {"float64": "f", "int64": "i", "bool": "b"}.get(m.dtype)
        if kind is not None:
            assert df[m.name].dtype.kind == kind, m.name
    for m in METRICS:
        for a in m.aggregates:
            if isinstance(a.threshold, str) and a.how != "pct_equal":
                assert a.threshold in MetricsConfig.model_fields, a.key


def test_generated_reference_is_well_formed_markdown() -> None:
    rows = [line for line in reference_markdown().splitlines() if line.startswith("|")]
    assert len(rows) == len(METRICS) + len(aggregate_keys()) + 4  # plus two header rows per table
    # 4 cells in the column table, 5 in the key table (with the interval method): no stray '|' in a doc
    assert all(line.count("|") == 5 for line in rows[: len(METRICS) + 2])
    assert all(line.count("|") == 6 for line in rows[len(METRICS) + 2 :])


def test_aggregate_keys_are_exactly_the_documented_ones() -> None:
    agg = aggregate_metrics(_frame(), inference_time_s=0.2)
    assert tuple(agg) == aggregate_keys()
    doc = aggregate_module.__doc__ or ""
    for key in agg:
        assert f"`{key}`" in doc, key  # the generated reference in the module docstring
    json.dumps(agg, allow_nan=False)


def test_config_key_is_stable_and_content_addressed() -> None:
    a, b = MetricsConfig(), MetricsConfig()
    assert a.key() == b.key() and len(a.key()) == 16
    assert MetricsConfig(low_ttc_s=3.0).key() != a.key()
    assert MetricsConfig(chunk_size=7).key() == a.key()  # engineering only: never changes a value
    assert MetricsConfig.from_json(MetricsConfig(pet_cell_m=1.0).to_json()) == MetricsConfig(pet_cell_m=1.0)
    assert a.key() == "93799ea10769b2f7"  # pinned: a change of defaults or fields must be deliberate
    with pytest.raises(ValueError):
        MetricsConfig(pet_cell_m=1.5)


def test_aggregate_applies_its_config_to_raw_values() -> None:
    df = _frame()  # min TTC 3 s, computed with the default config (low TTC < 2 s)
    assert df["min_ttc_s"].iloc[0] == pytest.approx(3.0, abs=1e-4) and not df["low_ttc"].iloc[0]
    assert aggregate_metrics(df)["lt_pct"] == 0.0
    assert aggregate_metrics(df, config=MetricsConfig(low_ttc_s=5.0))["lt_pct"] == 100.0
    five = MetricsConfig(low_ttc_s=5.0, ttc_cap_s=2.0, drac_high_mps2=0.5)
    agg = aggregate_metrics(df, config=five)
    assert agg["lt_pct"] == 100.0 and agg["ttc_s"] == 2.0 and agg["drac_high_pct"] == 100.0
    assert agg["metrics_config_key"] == five.key() and agg["low_ttc_s"] == 5.0


def test_aggregate_uses_the_recorded_config_not_defaults() -> None:
    cfg = MetricsConfig(low_ttc_s=5.0, ttc_cap_s=2.0)
    df = _frame(cfg)  # min TTC 3 s
    agg = aggregate_metrics(df)  # no config passed: the recorded one, not MetricsConfig()
    assert agg["ttc_s"] == 2.0 and agg["lt_pct"] == 100.0
    assert agg["metrics_config_key"] == cfg.key() == df["metrics_config_key"].iloc[0]
    assert recorded_config(df) == cfg


def test_aggregate_refuses_mismatched_or_mixed_configs() -> None:
    coarse = _frame(MetricsConfig(pet_cell_m=1.0))
    with pytest.raises(ValueError, match="pet_cell_m"):
        aggregate_metrics(coarse, config=MetricsConfig())
    with pytest.raises(ValueError, match="mixes"):
        aggregate_metrics(pd.concat([coarse, _frame()], ignore_index=True))
    # rows differing only in an aggregate threshold are fine (the config in effect decides)
    mixed = pd.concat([_frame(MetricsConfig(low_ttc_s=5.0)), _frame()], ignore_index=True)
    assert aggregate_metrics(mixed, config=MetricsConfig())["lt_pct"] == 0.0
    with pytest.raises(ValueError, match="records no metrics configuration"):
        aggregate_metrics(_frame().drop(columns=list(CONFIG_COLUMNS)))
    assert aggregate_metrics(_frame().drop(columns=list(CONFIG_COLUMNS)), config=MetricsConfig())["n"] == 1
    partly = pd.concat([_frame(), _frame().drop(columns=list(CONFIG_COLUMNS))], ignore_index=True)
    with pytest.raises(ValueError, match="1 of 2 rows record no metrics configuration"):
        aggregate_metrics(partly)


def test_pet_capped_mean_beside_the_finite_mean() -> None:
    b = concat_batches([make(CLOSING)] * 4)
    xy, v = constant_speed_plan(30.0)
    df = compute_metrics(b, np.repeat(xy, 4, 0), np.repeat(v, 4, 0)).to_frame()
    df["min_pet_s"] = [np.inf, 1.0, 2.0, 7.0]
    agg = aggregate_metrics(df)
    assert agg["pet_s"] == pytest.approx(10.0 / 3) and agg["pet_finite_n"] == 3
    assert agg["pet_capped_s"] == pytest.approx((5.0 + 1.0 + 2.0 + 5.0) / 4)  # cap 5 s
    assert aggregate_metrics(df, config=MetricsConfig(pet_cap_s=1.5))["pet_capped_s"] == pytest.approx(1.375)


def test_inference_times_of_any_length() -> None:
    df = _frame()
    assert aggregate_metrics(df, inference_time_s=[0.1, 0.3, np.nan])["inference_s"] == pytest.approx(0.2)
    assert aggregate_metrics(df)["inference_s"] is None


def test_markdown_footnote_is_balanced_and_shows_the_new_columns() -> None:
    b = make(CLOSING)
    agg = aggregate_metrics(compute_metrics(b, *human_future(b)), inference_time_s=0.1)
    md = render_markdown_table({"human": agg, "cv": aggregate_metrics(_frame(MetricsConfig(low_ttc_s=5.0)))})
    assert md.count("(") == md.count(")")
    assert "CR at fault" in md.splitlines()[0] and "TTC rear" in md
    assert "human: TTC 1/1" in md and "different metrics configurations" in md
    for line in md.splitlines():
        assert line.count("(") == line.count(")"), line


def test_more_than_eight_neighbour_slots() -> None:
    # a batch with 12 slots: 8 free-road slots, then a stopped car 60 m ahead in slot 10
    base = make([VehicleSpec(x0_m=-40.0, speed_mps=30.0)])
    extra = make([VehicleSpec(x0_m=60.0, speed_mps=0.0)] + [VehicleSpec(x0_m=500.0, speed_mps=30.0)] * 3)
    order = [1, 2, 0, 3]  # the stopped car lands in slot 8 + 2 = 10
    wide = replace(
        base,
        **{
            name: np.concatenate([getattr(base, name), getattr(extra, name)[:, order]], axis=1)
            for name in ("nbr_id", "nbr_class", "nbr_length_m", "nbr_width_m", "nbr_xy_m", "nbr_vxy_mps",
                         "nbr_valid", "nbr_lane_id")
        },
    )
    assert wide.nbr_xy_m.shape[1] == 12
    xy, v = constant_speed_plan(30.0)
    m = compute_metrics(wide, xy, v)
    assert m.collision[0] and (m.collision_step[0], m.collision_nbr[0]) == (46, 10)
    assert m.min_ttc_nbr[0] == 10 and m.collision_kind[0] == "front" and m.collision_at_fault[0]
    assert np.isfinite(m.min_pet_s[0])
    # the same vehicle appended to the 8-slot inputs as a context vehicle (slot 8)
    inp = inputs(base, xy, v)
    fs = extra.future_slice
    ctx = inp.with_neighbours(
        extra.nbr_xy_m[:, :1, fs], extra.nbr_vxy_mps[:, :1, fs], extra.nbr_valid[:, :1, fs],
        extra.nbr_length_m[:, :1], extra.nbr_width_m[:, :1],
    )
    assert ctx.nbr_xy_m.shape[1] == 9
    assert collisions(ctx).collision_nbr[0] == 8 and ttc_1d(ctx).min_ttc_nbr[0] == 8
    assert pet_grid(ctx).min_pet_nbr[0] in (0, 8)
