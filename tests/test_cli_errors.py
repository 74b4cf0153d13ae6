"""Every anticipated failure of the CLI: a non-zero exit, one or two lines naming the file, field or
address and what to do, no traceback, and no partial output (issue 15's table, one test per row).

Finished planners' results stay valid and a rerun resumes; a planner that failed leaves nothing.
"""

from __future__ import annotations

import errno
import json
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest
from highd_samples import sample_recording
from scenario_support import noisy_batch
from typer.testing import CliRunner

import letspi.evaluation.results as results
import letspi.scenario.store as store
from benchmarks.llm_server import Fault, LlmTestServer
from letspi.cli.app import app
from letspi.highd.io import write_recording
from letspi.planners.sf import SocialForcePlanner
from letspi.scenario.build import VehicleSpec, straight_road_scenario
from letspi.scenario.store import save_scenarios
from letspi.scenario.types import SCHEMA_VERSION, concat_batches

runner = CliRunner()
DEAD = "openai:foo@http://127.0.0.1:9/v1"  # port 9 (discard): nothing listens, connections are refused


def _scenario_file(tmp_path: Path, n: int = 4) -> Path:
    batch = concat_batches([
        straight_road_scenario(scenario_id=f"s{i}", neighbours=[VehicleSpec(25.0, 27.0)]) for i in range(n)
    ])
    return save_scenarios(batch, tmp_path / "s.arrow")


def _one_clear_error(result, *names: str, code: int = 2) -> str:  # type: ignore[no-untyped-def]
    """The failure is one or two lines (terminal wrapping aside) naming ``names``; returns them joined."""
    assert result.exit_code == code, result.output
    text = " ".join(result.output.split())
    assert "Traceback" not in result.output and "File \"" not in result.output
    assert text.count("error:") == 1, result.output
    for name in names:
        assert name in text, (name, result.output)
    assert result.exception is None or isinstance(result.exception, SystemExit)
    return text


def _files(directory: Path) -> list[str]:
    if not directory.exists():
        return []
    return sorted(str(p.relative_to(directory)) for p in directory.rglob("*") if p.is_file())


# ------------------------------------------------------------------------------------------------
# Unreachable server
# ------------------------------------------------------------------------------------------------


def test_plan_with_an_unreachable_server(tmp_path: Path) -> None:
    path = _scenario_file(tmp_path)
    result = runner.invoke(app, ["plan", "--scenarios", str(path), "--index", "0", "--llm", DEAD, "--no-cache",
                                 "--json"])
    text = _one_clear_error(result, "127.0.0.1:9", "start the server")
    assert "{" not in result.stdout, "no (empty) JSON on stdout"
    assert "rerun" in text


def test_evaluate_with_an_unreachable_server_keeps_finished_planners(tmp_path: Path) -> None:
    path = _scenario_file(tmp_path)
    out = tmp_path / "ev"
    args = ["evaluate", "--scenarios", str(path), "--planner", "sf", "--planner", "llm", "--out", str(out),
            "--no-cache"]
    result = runner.invoke(app, [*args, "--llm", DEAD])
    _one_clear_error(result, "127.0.0.1:9", "start the server", "rerun")
    files = _files(out)
    assert not [f for f in files if "per_scenario/llm" in f], files  # no config.json, no parts
    assert "run.json" in files and "per_scenario/sf/config.json" in files
    metrics = json.loads((out / "metrics.json").read_text())["planners"]
    assert set(metrics) == {"sf"} and metrics["sf"]["n"] == 4  # the finished planner is scored
    sf_parts = sorted((out / "per_scenario" / "sf").glob("part-*.parquet"))
    assert len(sf_parts) == 1
    # a rerun with a working model resumes: sf is not recomputed, llm completes
    again = runner.invoke(app, [*args, "--llm", "scripted:default"])
    assert again.exit_code == 0, again.output
    assert sorted((out / "per_scenario" / "sf").glob("part-*.parquet")) == sf_parts
    metrics = json.loads((out / "metrics.json").read_text())["planners"]
    assert metrics["sf"]["n"] == 4 and metrics["llm"]["n"] == 4


def test_evaluate_with_only_a_failing_planner_leaves_nothing(tmp_path: Path) -> None:
    path = _scenario_file(tmp_path)
    out = tmp_path / "ev"
    result = runner.invoke(app, ["evaluate", "--scenarios", str(path), "--planner", "llm", "--out", str(out),
                                 "--llm", DEAD, "--no-cache"])
    _one_clear_error(result, "127.0.0.1:9")
    assert _files(out) == []  # no run.json without results


def test_collect_with_an_unreachable_server_leaves_no_empty_bank(tmp_path: Path) -> None:
    path = _scenario_file(tmp_path)
    memory = tmp_path / "memory.sqlite"
    args = ["collect", "--scenarios", str(path), "--memory", str(memory), "--no-cache"]
    result = runner.invoke(app, [*args, "--llm", DEAD])
    _one_clear_error(result, "127.0.0.1:9", "start the server")
    assert _files(tmp_path) == ["s.arrow"]  # the bank it would have created is gone
    assert runner.invoke(app, [*args, "--llm", "scripted:default"]).exit_code == 0
    size = memory.stat().st_size
    result = runner.invoke(app, [*args, "--llm", DEAD])  # a bank with experiences stays
    _one_clear_error(result, "127.0.0.1:9")
    assert memory.stat().st_size >= size


def test_model_not_found(tmp_path: Path) -> None:
    path = _scenario_file(tmp_path)
    result = runner.invoke(app, ["plan", "--scenarios", str(path), "--index", "0", "--llm",
                                 "llamacpp:does-not-exist", "--json"])
    _one_clear_error(result, "does-not-exist", "smollm2-135m")
    assert result.stdout == ""
    missing = tmp_path / "nowhere.gguf"
    result = runner.invoke(app, ["plan", "--scenarios", str(path), "--index", "0", "--llm", f"llamacpp:{missing}"])
    _one_clear_error(result, str(missing), "letspi llm models")
    out = tmp_path / "ev"
    with LlmTestServer(fault=lambda r: Fault(404, "model 'nope' not found, try pulling it first")) as srv:
        result = runner.invoke(app, ["evaluate", "--scenarios", str(path), "--planner", "llm", "--out", str(out),
                                     "--llm", srv.spec("nope"), "--no-cache"])
    _one_clear_error(result, "'nope'", srv.base_url)
    assert _files(out) == []


def test_bad_spec(tmp_path: Path) -> None:
    path = _scenario_file(tmp_path)
    result = runner.invoke(app, ["plan", "--scenarios", str(path), "--index", "0", "--llm", "olama:x"])
    _one_clear_error(result, "olama:x", "unknown backend", "ollama:MODEL")
    out = tmp_path / "ev"
    result = runner.invoke(app, ["evaluate", "--scenarios", str(path), "--planner", "sf", "--planner", "llm",
                                 "--llm", "olama:x", "--out", str(out)])
    _one_clear_error(result, "olama:x")
    assert _files(out) == []  # refused before any planner ran


# ------------------------------------------------------------------------------------------------
# Damaged inputs
# ------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def big_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = save_scenarios(noisy_batch(520, seed=1), tmp_path_factory.mktemp("big") / "big.arrow")
    assert path.stat().st_size > 2_000_000
    return path


def _damaged_commands(path: Path, out: Path) -> list[list[str]]:
    return [
        ["evaluate", "--scenarios", str(path), "--planner", "sf", "--out", str(out)],
        ["plan", "--scenarios", str(path), "--index", "0", "--planner", "sf", "--json"],
        ["data", "info", str(path)],
    ]


def test_scenario_file_with_one_megabyte_zeroed(big_file: Path, tmp_path: Path) -> None:
    data = big_file.read_bytes()
    mid = len(data) // 2
    damaged = tmp_path / "zeroed.arrow"
    damaged.write_bytes(data[: mid - 500_000] + b"\x00" * 1_000_000 + data[mid + 500_000 :])
    out = tmp_path / "ev"
    for args in _damaged_commands(damaged, out):
        result = runner.invoke(app, args)
        _one_clear_error(result, str(damaged), "truncated or corrupted", "letspi data scenarios")
        assert result.stdout == ""
    assert _files(out) == []


@pytest.mark.parametrize("keep", [0.0, 0.3, 0.97])
def test_truncated_scenario_file(tmp_path: Path, keep: float) -> None:
    data = _scenario_file(tmp_path).read_bytes()
    damaged = tmp_path / "cut.arrow"
    damaged.write_bytes(data[: int(len(data) * keep)])
    out = tmp_path / "ev"
    for args in _damaged_commands(damaged, out):
        result = runner.invoke(app, args)
        _one_clear_error(result, str(damaged), "truncated or corrupted", "letspi data scenarios")
    assert _files(out) == []


def test_scenario_file_of_an_old_schema(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    batch = straight_road_scenario(neighbours=[VehicleSpec(25.0, 27.0)])
    with monkeypatch.context() as patch:
        patch.setattr(store, "SCHEMA_VERSION", SCHEMA_VERSION - 1)
        old = save_scenarios(batch, tmp_path / "old.arrow")
    out = tmp_path / "ev"
    for args in _damaged_commands(old, out):
        result = runner.invoke(app, args)
        _one_clear_error(result, str(old), f"version {SCHEMA_VERSION - 1} found", "letspi data scenarios")
    assert _files(out) == []


def test_malformed_highd(tmp_path: Path) -> None:
    highd = tmp_path / "highd"
    highd.mkdir()
    write_recording(sample_recording(), highd)
    tracks = highd / "01_tracks.csv"
    lines = tracks.read_text().splitlines()
    header = lines[0].split(",")
    row = lines[5].split(",")
    row[header.index("xVelocity")] = "fast"
    lines[5] = ",".join(row)
    tracks.write_text("\n".join(lines) + "\n")
    out = tmp_path / "s.arrow"
    result = runner.invoke(app, ["data", "scenarios", "--highd", str(highd), "--out", str(out)])
    _one_clear_error(result, f"{highd}/01_tracks.csv", "xVelocity", "line 6", "--recordings")
    assert not out.exists() and _files(tmp_path / "highd") == sorted(p.name for p in highd.iterdir())


# ------------------------------------------------------------------------------------------------
# Output location
# ------------------------------------------------------------------------------------------------


def test_output_dir_that_cannot_be_created(tmp_path: Path) -> None:
    path = _scenario_file(tmp_path)
    blocker = tmp_path / "afile"
    blocker.write_text("not a directory")
    result = runner.invoke(app, ["evaluate", "--scenarios", str(path), "--planner", "sf", "--out",
                                 str(blocker / "ev")])
    _one_clear_error(result, str(blocker / "ev"), "not a directory", "--out")


@pytest.fixture
def small_mount(tmp_path: Path) -> Iterator[Path]:
    """A 64 KiB tmpfs (needs root: skipped otherwise)."""
    mount = tmp_path / "mnt"
    mount.mkdir()
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(mount)], capture_output=True,
                          check=False)
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {done.stderr.decode().strip()}")
    try:
        yield mount
    finally:
        subprocess.run(["umount", "-l", str(mount)], check=False)


def test_unwritable_output_dir(tmp_path: Path, small_mount: Path) -> None:
    path = _scenario_file(tmp_path)
    subprocess.run(["mount", "-o", "remount,ro", str(small_mount)], check=True)
    result = runner.invoke(app, ["evaluate", "--scenarios", str(path), "--planner", "sf", "--out",
                                 str(small_mount / "ev")])
    _one_clear_error(result, str(small_mount / "ev"), "--out")


def test_disk_full(tmp_path: Path, small_mount: Path) -> None:
    path = save_scenarios(noisy_batch(40), tmp_path / "noisy.arrow")
    out = small_mount / "ev"
    args = ["evaluate", "--scenarios", str(path), "--planner", "human", "--planner", "sf", "--out", str(out)]
    result = runner.invoke(app, args)
    _one_clear_error(result, "no space left", "Free disk space")
    leftovers = [f for f in _files(out) if f.endswith(".tmp")]
    assert leftovers == []
    # scenario files too
    result = runner.invoke(app, ["data", "info", str(path)])
    assert result.exit_code == 0


def test_disk_full_without_root(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The same through a failing write (any user): ENOSPC from the part writer."""

    def full(*args: object, **kwargs: object) -> None:
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(results.pq, "write_table", full)
    path = _scenario_file(tmp_path)
    out = tmp_path / "ev"
    result = runner.invoke(app, ["evaluate", "--scenarios", str(path), "--planner", "sf", "--out", str(out)])
    _one_clear_error(result, "no space left", "Free disk space")
    assert _files(out) == []


# ------------------------------------------------------------------------------------------------
# Interrupted run
# ------------------------------------------------------------------------------------------------


def test_interrupted_run_is_one_line_and_resumes(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = _scenario_file(tmp_path)
    out = tmp_path / "ev"
    args = ["evaluate", "--scenarios", str(path), "--planner", "human", "--planner", "sf", "--out", str(out)]

    def interrupted(self: object, batch: object) -> None:
        raise KeyboardInterrupt

    with monkeypatch.context() as patch:
        patch.setattr(SocialForcePlanner, "plan", interrupted)
        result = runner.invoke(app, args)
    assert result.exit_code == 130, result.output
    # one line (Ctrl-C is no error): what is kept of the 2 planners x 4 scenarios, and what to do
    assert result.output.strip().splitlines()[-1] == "interrupted: 4 of 8 stored; rerun the same command to resume"
    assert "error" not in result.output and "Traceback" not in result.output
    human_parts = sorted((out / "per_scenario" / "human").glob("part-*.parquet"))
    assert len(human_parts) == 1 and not (out / "per_scenario" / "sf").exists()
    again = runner.invoke(app, args)
    assert again.exit_code == 0, again.output
    assert sorted((out / "per_scenario" / "human").glob("part-*.parquet")) == human_parts
    metrics = json.loads((out / "metrics.json").read_text())["planners"]
    assert metrics["human"]["n"] == 4 and metrics["sf"]["n"] == 4


def test_debug_shows_the_traceback(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("LETSPI_DEBUG", "0")  # restored afterwards (--debug sets it for the process)
    path = _scenario_file(tmp_path)
    result = runner.invoke(app, ["--debug", "plan", "--scenarios", str(path), "--index", "0", "--llm", "olama:x"])
    assert result.exit_code != 0 and result.exception is not None
    assert not isinstance(result.exception, SystemExit)


# ------------------------------------------------------------------------------------------------
# Benchmark-suite traffic (generator seeds 1000-1999) is never fitted or labelled on
# ------------------------------------------------------------------------------------------------


def _file_from_seeds(tmp_path: Path, *seeds: int) -> Path:
    batch = concat_batches([straight_road_scenario(scenario_id=f"s{i}", neighbours=[VehicleSpec(25.0, 27.0)])
                            for i in range(4)])
    generation = [{"seed": s, "recording": k + 1, "minutes": 1.0} for k, s in enumerate(seeds)]
    return save_scenarios(batch, tmp_path / f"seeds{'_'.join(map(str, seeds))}.arrow",
                          extra_meta={"provenance": {"source": "gen", "generation": generation}})


@pytest.mark.parametrize("command", [["fit", "sf", "--evaluations", "1"], ["fit", "frenet", "--rounds", "0"],
                                     ["train", "llm-data", "--n-random", "1", "--n-rounds", "0"]])
def test_fitting_and_labelling_refuse_suite_traffic(tmp_path: Path, command: list[str]) -> None:
    pytest.importorskip("letspi_train", reason="letspi-train is not installed (pip install -e packages/letspi-train)")
    path = _file_from_seeds(tmp_path, 7, 1003)
    out = tmp_path / "out"
    result = runner.invoke(app, [*command, "--scenarios", str(path), "--out", str(out)])
    _one_clear_error(result, path.name, "seed(s) 1003", "reserved for the benchmark suites (1000-1999)")
    assert not out.exists()


def test_suite_seed_check_reads_the_recorded_seeds(tmp_path: Path) -> None:
    from letspi.scenario.provenance import generator_seeds, refuse_suite_traffic
    from letspi.scenario.store import read_scenario_meta

    meta = read_scenario_meta(_file_from_seeds(tmp_path, 999, 2000, 999))
    assert generator_seeds(meta) == [999, 2000]
    refuse_suite_traffic(Path("x.arrow"), meta)  # just outside the reserved range on both sides: accepted
    assert generator_seeds(read_scenario_meta(_scenario_file(tmp_path))) == []  # real HighD / older files
