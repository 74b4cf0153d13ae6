"""``letspi data``: generate HighD-format traffic with SUMO, extract planning scenarios, inspect both."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import numpy as np
import typer

from letspi.cli.common import command_line, console, progress_bar, user_errors
from letspi.constants import DEFAULT_STRIDE_FRAMES, T0_INDEX
from letspi.fsutil import writer_lock
from letspi.highd.criticality import profile_directory, profile_table
from letspi.highd.events import read_events
from letspi.highd.io import read_recordings
from letspi.highd.marginals import compare_table, traffic_marginals
from letspi.scenario.extract import critical_windows, enumerate_windows, extract_scenarios
from letspi.scenario.provenance import generation_records
from letspi.scenario.store import load_scenarios, read_scenario_meta, save_scenarios
from letspi.trafficgen.config import traffic_preset, with_overrides
from letspi.trafficgen.generate import generate_highd
from letspi.trafficgen.ssm import ssm_check

app = typer.Typer(help="HighD data: generate with SUMO, extract scenarios, inspect.",
                  no_args_is_help=True, rich_markup_mode=None)


def _parse_ids(text: str | None) -> list[int] | None:
    if not text:
        return None
    try:
        return [int(v) for v in text.split(",") if v.strip()]
    except ValueError as exc:
        raise typer.BadParameter(f"recording ids must be comma-separated integers, got {text!r}") from exc


def _parse_settings(items: list[str] | None) -> dict[str, str]:
    out: dict[str, str] = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise typer.BadParameter(f"--set expects KEY=VALUE (e.g. events.cut_in_per_min=2), got {item!r}")
        out[key.strip()] = value.strip()
    return out


@app.command()
def generate(
    out: Annotated[Path, typer.Option(help="Directory for the NN_*.csv HighD files (and NN_events.csv).")],
    minutes: Annotated[float, typer.Option(help="Simulated minutes of recording (after warm-up).")] = 3.0,
    seed: Annotated[int, typer.Option(help="Random seed: same seed, same traffic.")] = 0,
    lanes_per_direction: Annotated[int, typer.Option(min=2, max=3, help="2 or 3 lanes per direction.")] = 3,
    flow: Annotated[float | None, typer.Option(help="Inflow per direction [veh/h]; default: generator's.")] = None,
    recording_minutes: Annotated[
        float | None, typer.Option(help="Split into recordings of this many minutes (default: one).")] = None,
    criticality: Annotated[
        str, typer.Option(help="Traffic preset: calm (no scripted events), highd (default), stress, realistic "
                               "(calibrated to highD's published marginals).")] = "highd",
    layout: Annotated[
        str | None, typer.Option(help="Road layout: straight, on_ramp, lane_drop (= --set layout.kind=...).")] = None,
    settings: Annotated[list[str] | None, typer.Option(
        "--set", help="Override one traffic knob, KEY=VALUE (repeatable), e.g. events.cut_in_per_min=2 "
                      "or drivers.reaction_time_s=0.3,1.2; --show-config lists them.")] = None,
    show_config: Annotated[bool, typer.Option(help="Print the resolved traffic configuration and exit.")] = False,
) -> None:
    """Simulate highway traffic in SUMO as HighD recordings. Both directions, with an events file per recording."""
    with user_errors():
        overrides = _parse_settings(settings)
        if layout is not None:
            overrides["layout.kind"] = layout
        cfg = with_overrides(traffic_preset(criticality), overrides)
        if show_config:
            typer.echo(json.dumps(cfg.to_dict(), indent=2))
            return
        with writer_lock(out, command_line()), progress_bar() as bar:
            task = bar.add_task("simulating", total=100.0)
            report = generate_highd(
                out,
                minutes=minutes,
                seed=seed,
                lanes_per_direction=lanes_per_direction,
                flow_veh_per_h=flow,
                recording_minutes=recording_minutes,
                traffic=cfg,
                progress=lambda frac: bar.update(task, completed=100.0 * frac),
            )
    console.print(f"wrote {len(report.paths)} recording(s) to {out} ({cfg.name}, {cfg.layout.kind}): "
                  f"{report.events_written} scripted events, {report.perceived_lane_changes} followers with "
                  f"lane-change perception")
    if report.failed_events:
        console.print(f"{report.failed_events} forced lane change(s) SUMO did not carry out (not written)")
    if report.rejected:
        console.print("re-simulated after contact: " + "; ".join(report.rejected))
    console.print(f"speed: {report.simulated_minutes:g} simulated min in {report.wall_time_s:.1f} s wall = "
                  f"{report.sim_minutes_per_wall_s:.3f} sim-min per wall s (SUMO stepping "
                  f"{report.sumo_wall_time_s:.1f} s wall, {report.sumo_cpu_time_s:.1f} s CPU; includes the 90 s "
                  "warm-up and any re-simulation)")


@app.command("ssm-check")
def ssm_check_command(
    minutes: Annotated[float, typer.Option(help="Simulated minutes of the one recording compared.")] = 5.0,
    seed: Annotated[int, typer.Option(help="Random seed of the traffic.")] = 0,
    criticality: Annotated[str, typer.Option(help="Traffic preset: calm, highd, stress.")] = "highd",
    settings: Annotated[list[str] | None, typer.Option("--set", help="Override a traffic knob, KEY=VALUE.")] = None,
    keep: Annotated[Path | None, typer.Option(help="Also write the recording and SUMO's SSM XML here.")] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Machine-readable output.")] = False,
) -> None:
    """Compare the recordings' TTC with SUMO's SSM device. TTC per frame and per-vehicle minimum."""
    with user_errors():
        cfg = with_overrides(traffic_preset(criticality), _parse_settings(settings))
        with progress_bar() as bar:
            task = bar.add_task("simulating with SSM devices", total=100.0)
            result = ssm_check(minutes=minutes, seed=seed, traffic=cfg, keep_dir=keep,
                               progress=lambda f: bar.update(task, completed=100.0 * f))
    if as_json:
        typer.echo(json.dumps(result.to_dict(), indent=2))
    else:
        for k, v in result.to_dict().items():
            typer.echo(f"{k}: {v:.4g}" if isinstance(v, float) else f"{k}: {v}")


@app.command()
def scenarios(
    highd: Annotated[Path, typer.Option(help="Directory with NN_tracks.csv, NN_tracksMeta.csv, NN_recordingMeta.csv.")],
    out: Annotated[Path, typer.Option(help="Output scenario file (Arrow IPC, zstd; .parquet suffix: Parquet).")],
    max: Annotated[int | None, typer.Option("--max", help="Sample at most N scenarios (paper: 10,000).")] = None,
    seed: Annotated[int, typer.Option(help="Seed of the random sample.")] = 0,
    stride: Annotated[int, typer.Option(min=1, help="Sliding-window stride [frames].")] = DEFAULT_STRIDE_FRAMES,
    recordings: Annotated[str | None, typer.Option(help="Comma-separated recording ids (default: all).")] = None,
    focus: Annotated[str, typer.Option(help="uniform (the paper: uniform random windows) or critical "
                                            "(oversample windows whose recorded future holds a conflict)")] = "uniform",
    critical_share: Annotated[float, typer.Option(
        help="With --focus critical: the share of scenarios drawn from windows with a conflict of the ego "
             "(TTC < 3 s, DRAC > 3 m/s^2, or a scripted event).")] = 0.5,
) -> None:
    """Cut recordings into 8 s ego-centric scenarios. 3 s history and 5 s future; neighbours are chosen at
    t = 0 from what is visible then; other vehicles near the ego's recorded future are kept as context the
    evaluation scores and planners never see."""
    with user_errors():
        if focus not in ("uniform", "critical"):
            raise ValueError(f"--focus must be uniform or critical, got {focus!r}")
        share = critical_share if focus == "critical" else 0.0
        recs = read_recordings(highd, _parse_ids(recordings))
        events = {r.recording_id: read_events(highd, r.recording_id) for r in recs}
        windows = enumerate_windows(recs, stride)
        total = len(windows)
        n = total if max is None else min(max, total)
        n_critical = int(critical_windows(recs, windows, events).sum())
        with progress_bar() as bar:
            task = bar.add_task("extracting", total=n)
            batch = extract_scenarios(
                recs, max_scenarios=max, seed=seed, stride_frames=stride, critical_share=share, events=events,
                progress=lambda k: bar.advance(task, k),
            )
        provenance = {
            "source": str(highd), "recordings": [r.recording_id for r in recs], "stride_frames": stride,
            "max": max, "seed": seed, "windows_available": total, "focus": focus, "critical_share": share,
            "critical_windows_available": n_critical,
            "generation": generation_records(highd, [r.recording_id for r in recs]),
        }
        save_scenarios(batch, out, extra_meta={"provenance": provenance})
    console.print(f"wrote {len(batch)} of {total} scenarios to {out} ({n_critical} windows have a conflict "
                  f"in their future; focus {focus})")


@app.command()
def info(
    paths: Annotated[list[Path], typer.Argument(help="A scenario file, or one or more HighD directories.")],
    criticality: Annotated[bool, typer.Option(
        "--criticality", help="HighD directories: per-vehicle minTTC/minTHW/minDHW shares, DRAC, lane changes, "
                              "flow per lane, trucks, contacts, events (several directories side by side).")] = False,
    compare_highd: Annotated[bool, typer.Option(
        "--compare-highd", help="HighD directories: lane changes, truck share, time in view, speed by class and "
                                "lane, time headway, beside the values the highD authors published.")] = False,
    as_json: Annotated[bool, typer.Option("--json", help="Machine-readable output.")] = False,
) -> None:
    """Summarise a scenario file or HighD directories. For HighD directories: their criticality profile."""
    with user_errors():
        dirs = [p for p in paths if p.is_dir()]
        if dirs:
            if len(dirs) != len(paths):
                raise ValueError("give either one scenario file or HighD directories, not both")
            if compare_highd:
                measured = {str(d): traffic_marginals(read_recordings(d)) for d in dirs}
                typer.echo(json.dumps(measured, indent=2) if as_json else compare_table(measured))
                return
            _info_highd(dirs, criticality=criticality, as_json=as_json)
            return
        if compare_highd:
            raise ValueError("--compare-highd needs HighD directories (NN_tracks.csv, ...), not a scenario file")
        if criticality:
            raise ValueError("--criticality needs HighD directories (NN_tracks.csv, ...), not a scenario file")
        if len(paths) != 1:
            raise ValueError(f"one scenario file at a time, got {len(paths)}")
        _info_scenarios(paths[0], as_json=as_json)


def _info_highd(dirs: list[Path], *, criticality: bool, as_json: bool) -> None:
    profiles = {str(d): profile_directory(d) for d in dirs}
    if not criticality:
        summary = {name: {"recordings": p.n_recordings, "recorded_minutes": p.recorded_minutes,
                          "vehicles": p.n_vehicles, "truck_share": p.truck_share, "events_by_kind": p.events_by_kind}
                   for name, p in profiles.items()}
        if as_json:
            typer.echo(json.dumps(summary, indent=2))
        else:
            for name, values in summary.items():
                typer.echo(f"{name}: " + ", ".join(f"{k} {v}" for k, v in values.items()))
        return
    if as_json:
        typer.echo(json.dumps({name: p.to_dict() for name, p in profiles.items()}, indent=2))
    else:
        typer.echo(profile_table(profiles))


def _info_scenarios(scenarios_file: Path, *, as_json: bool) -> None:
    meta = read_scenario_meta(scenarios_file)
    batch = load_scenarios(scenarios_file)
    visible = batch.nbr_valid[:, :, T0_INDEX].sum(axis=1)
    lane_changes = np.any(batch.ego_lane_id != batch.ego_lane_id[:, :1], axis=1)
    summary = {
        "file": str(scenarios_file),
        "schema_version": meta["schema_version"],
        "n_scenarios": len(batch),
        "recordings": sorted({int(r) for r in batch.recording_id}),
        "trucks_as_ego": int((batch.ego_class == 1).sum()),
        "mean_visible_neighbours_t0": float(visible.mean()) if len(batch) else 0.0,
        "ego_lane_change_in_window": int(lane_changes.sum()),
        "mean_ego_speed_t0_mps": float(np.hypot(*batch.ego_vxy0_mps.T).mean()) if len(batch) else 0.0,
        "provenance": meta.get("provenance"),
    }
    if as_json:
        typer.echo(json.dumps(summary, indent=2))
    else:
        for k, v in summary.items():
            typer.echo(f"{k}: {v}")
