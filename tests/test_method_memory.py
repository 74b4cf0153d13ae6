"""Memory bank: round trip, uniqueness, WAL, concurrent writers, kill -9 durability, subsets, retrieval bench."""

from __future__ import annotations

import multiprocessing as mp
import os
import signal
import sqlite3
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from benchmarks.retrieval import bench_retrieval
from letspi.method.matching import top_k
from letspi.method.memory import SCHEMA_VERSION, Experience, MemoryBank, MemoryBankError
from letspi.method.reflection import Proposal, ReflectionContext, reflect
from letspi.method.thresholds import ReflectionThresholds
from letspi.physics.params import SocialForceParams
from letspi.scenario.build import VehicleSpec, straight_road_scenario
from letspi.scenario.features import scenario_features
from letspi.scenario.identity import scenario_digests


def _exp(i: int, config_key: str = "cfg", validated: bool = True, fallback: bool = False) -> Experience:
    f = (float(i % 9), 20.0 + i % 17, float(i % 2), 5.0 + i % 50, 30.0 + i % 40, 25.0)
    metrics = {"min_ttc_s": float("inf"), "min_path_gap_m": 10.0 + i, "collision": 0.0, "safe": 1.0}
    return Experience(
        scenario_id=f"s{i}", scenario_digest=f"d{i}", recording_key="rec", recording_id=1, ego_id=i, frame0=100,
        config_key=config_key, features=f, params=SocialForceParams(k_np=20.0 + i % 7), fallback=fallback,
        lon_factor=0.5, lane_factor=-0.25, metrics_before={**metrics, "min_ttc_s": 0.8}, metrics_after=metrics,
        iterations=[{"iteration": 0, "metrics": metrics}], model="test-model", prompt="p", reply="r",
        rationale="because", validated=validated,
    )


def test_round_trip_from_reflection(tmp_path: Path) -> None:
    sc = straight_road_scenario(ego_speed_mps=33.0, neighbours=[VehicleSpec(x0_m=40.0, speed_mps=20.0)],
                                scenario_id="r01_v5_f100")

    def propose(ctx: ReflectionContext) -> Proposal:
        k = 3.0 if ctx.previous is None else ctx.previous.params.k_np * 2.5
        lon = 0.0 if ctx.previous is None else min(1.0, ctx.previous.lon_factor + 0.5)
        return Proposal(SocialForceParams(k_np=k), lon_factor=lon, rationale=f"it{ctx.iteration}",
                        prompt=f"prompt {ctx.iteration}", reply=f"reply {ctx.iteration}")

    res = reflect(sc, propose, ReflectionThresholds(max_decel_mps2=None))
    assert res.validated and res.n_refinements >= 1
    exp = Experience.from_reflection(res, sc, scenario_digest=str(scenario_digests(sc)[0]), config_key="m1",
                                     model="scripted")
    assert exp.features == tuple(scenario_features(sc)[0]) and exp.recording_key == "synthetic"
    with MemoryBank.open(tmp_path / "mem.sqlite") as bank:
        assert bank.add(exp)
        (got,) = bank.get(bank.features_matrix().ids)
    assert got == exp and got.id == 1 and got.created_at
    assert got.n_iterations == len(res.iterations) and got.reply == f"reply {res.final_index}"
    assert got.metrics_after["min_rear_ttc_s"] == float("inf")  # non-finite floats survive JSON
    assert got.metrics_after["min_ttc_s"] >= 1.5 and got.metrics_before["safe"] == 0.0
    assert got.iterations[0]["report_text"].startswith("Safety analysis")


def test_unique_conflict_count_and_wal(tmp_path: Path) -> None:
    path = tmp_path / "mem.sqlite"
    with MemoryBank.open(path) as bank:
        assert bank.journal_mode() == "wal"
        assert bank.add(_exp(1)) and bank.add(_exp(2)) and bank.add(_exp(3, validated=False))
        assert bank.add(_exp(1, config_key="other"))  # same scenario, other configuration
        assert bank.count() == 3 and bank.count(validated_only=False) == 4
        assert not bank.add(_exp(1))
        assert bank.add_many([_exp(1), _exp(2), _exp(4)]) == 1
        assert bank.count(validated_only=False) == 5 and bank.count(config_key="cfg") == 3
        assert bank.has("d1", "cfg") and not bank.has("d9", "cfg")
        assert [e.scenario_id for e in bank.iter_experiences(batch_size=2)] == ["s1", "s2", "s3", "s1", "s4"]
    con = sqlite3.connect(path)
    assert con.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    assert con.execute("SELECT version FROM schema_version").fetchall() == [(SCHEMA_VERSION,)]
    con.close()


def test_features_matrix_cache_refreshes_on_other_writers(tmp_path: Path) -> None:
    path = tmp_path / "mem.sqlite"
    with MemoryBank.open(path) as writer, MemoryBank.open(path, readonly=True) as reader:
        writer.add(_exp(1))
        m1 = reader.features_matrix()
        assert len(m1) == 1 and reader.features_matrix() is m1  # cached
        writer.add(_exp(2))
        m2 = reader.features_matrix()
        assert len(m2) == 2 and m2.features[1].tolist() == list(_exp(2).features)
        idx, sims = top_k(np.array(_exp(2).features), m2.features, 1)
        assert m2.ids[idx[0, 0]] == 2 and sims[0, 0] == 1.0


def test_sample_fraction_is_reproducible_nested_and_a_filter(tmp_path: Path) -> None:
    with MemoryBank.open(tmp_path / "mem.sqlite") as bank:
        bank.add_many([_exp(i) for i in range(200)])
        s10, s50 = bank.sample_fraction(0.1, seed=7), bank.sample_fraction(0.5, seed=7)
        assert len(s10) == 20 and len(s50) == 100
        assert set(s10.ids) <= set(s50.ids)
        assert np.array_equal(s10.ids, bank.sample_fraction(0.1, seed=7).ids)
        assert not np.array_equal(s10.ids, bank.sample_fraction(0.1, seed=8).ids)
        assert len(bank.sample_fraction(0.0)) == 0 and len(bank.sample_fraction(1.0)) == 200
        fm = s10.features_matrix()
        assert fm.features.tolist() == [list(e.features) for e in s10.iter_experiences()]
        assert bank.count(validated_only=False) == 200  # nothing copied


def _writer(path: str, start: int, n: int, overlap: int) -> None:
    # each process: its own connection; inserts its range plus an overlap shared with the other writer
    with MemoryBank.open(path) as bank:
        for i in range(start, start + n):
            bank.add(_exp(i))
        for i in range(overlap):
            bank.add(_exp(10_000 + i))


def test_two_processes_write_concurrently(tmp_path: Path) -> None:
    path = str(tmp_path / "mem.sqlite")
    MemoryBank.open(path).close()
    ctx = mp.get_context("fork")
    procs = [ctx.Process(target=_writer, args=(path, k * 1000, 150, 50)) for k in range(2)]
    for p in procs:
        p.start()
    for p in procs:
        p.join(120)
        assert p.exitcode == 0
    with MemoryBank.open(path) as bank:
        ids = [e.scenario_id for e in bank.iter_experiences()]
        assert len(ids) == len(set(ids)) == 2 * 150 + 50
        assert bank.integrity_check() == "ok"


_KILL_CHILD = """
import sys
from letspi.method.memory import SCHEMA_VERSION, Experience, MemoryBank, MemoryBankError
from letspi.physics.params import SocialForceParams
bank = MemoryBank.open(sys.argv[1])
i = 0
while True:
    m = {"min_ttc_s": 2.0, "safe": 1.0}
    e = Experience(f"k{i}", f"k{i}", "rec", 1, i, 100, "cfg", (1.0, 2.0, 0.0, 3.0, 4.0, 5.0), SocialForceParams(),
                   0.4, 0.0, m, m, [{"iteration": 0, "metrics": m, "pad": "x" * 2000}], "model", "prompt", "reply",
                   "why", True)
    bank.add(e)
    print(f"k{i}", flush=True)  # printed only after the commit returned
    i += 1
"""


def test_kill_9_while_inserting_loses_no_committed_row(tmp_path: Path) -> None:
    path = tmp_path / "mem.sqlite"
    proc = subprocess.Popen([sys.executable, "-c", _KILL_CHILD, str(path)], stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    committed = []
    deadline = time.monotonic() + 60
    while len(committed) < 150 and time.monotonic() < deadline:
        line = proc.stdout.readline()
        if not line:
            break
        committed.append(line.strip())
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait(10)
    committed += [line.strip() for line in proc.stdout if line.strip()]  # lines flushed before the kill
    proc.stdout.close()
    assert len(committed) >= 150
    with MemoryBank.open(path) as bank:
        assert bank.integrity_check() == "ok"
        stored = [e.scenario_id for e in bank.iter_experiences()]
        assert set(committed) <= set(stored) and len(stored) == len(set(stored))
        # a resumed run adds nothing twice
        assert not bank.add(replace(_exp(0), scenario_id="k0", scenario_digest="k0"))


def test_fallback_rows_are_replaced_real_rows_are_kept(tmp_path: Path) -> None:
    with MemoryBank.open(tmp_path / "mem.sqlite") as bank:
        assert bank.add(_exp(1, validated=False, fallback=True))
        assert not bank.has("d1", "cfg") and bank.count() == 0
        assert bank.add(_exp(1))  # the retry replaces the fallback
        assert bank.has("d1", "cfg") and bank.count() == 1 and bank.count(validated_only=False) == 1
        assert not bank.add(_exp(1, validated=False, fallback=True))  # never the other way round
        assert not next(bank.iter_experiences()).fallback
    with pytest.raises(ValueError, match="a fallback result cannot be validated"):
        _exp(2, validated=True, fallback=True)
    with pytest.raises(ValueError, match="s3: matching feature.*min_dist_m not finite"):
        replace(_exp(3), features=(1.0, 2.0, 0.0, float("nan"), 4.0, 5.0))


def test_old_schema_is_a_clear_error(tmp_path: Path) -> None:
    path = tmp_path / "old.sqlite"
    con = sqlite3.connect(path)
    con.execute("CREATE TABLE schema_version (version INTEGER NOT NULL)")
    con.execute("INSERT INTO schema_version VALUES (1)")
    con.commit()
    con.close()
    with pytest.raises(MemoryBankError, match="old.sqlite: memory bank schema version 1, this letspi reads version 2"):
        MemoryBank.open(path)


@pytest.mark.parametrize("n", [2000])
def test_bench_retrieval_small(n: int, tmp_path: Path) -> None:
    out = bench_retrieval((n,), n_queries=10, workdir=tmp_path)
    row = out["sizes"][n]
    assert row["load_s"] > 0 and row["topk_single_ms"] > 0 and row["retrieval_single_ms"] > 0
