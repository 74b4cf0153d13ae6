"""``letspi data``: generate HighD-format traffic with SUMO and extract planning scenarios."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import numpy as np
import typer

from letspi.cli.common import console, progress_bar, user_errors
from letspi.constants import DEFAULT_STRIDE_FRAMES, T0_INDEX
from letspi.highd.io import read_recordings
from letspi.scenario.extract import enumerate_windows, extract_scenarios
from letspi.scenario.store import load_scenarios, read_scenario_meta, save_scenarios
from letspi.sumo.generate import generate_recordings

app = typer.Typer(help="HighD data: generate with SUMO, extract scenarios, inspect.",
                  no_args_is_help=True, rich_markup_mode=None)


def _parse_ids(text: str | None) -> list[int] | None:
    if not text:
        return None
    try:
        return [int(v) for v in text.split(",") if v.strip()]
    except ValueError as exc:
        raise typer.BadParameter(f"recording ids must be comma-separated integers, got {text!r}") from exc


@app.command()
def generate(
    out: Annotated[Path, typer.Option(help="Directory for the NN_*.csv HighD files.")],
    minutes: Annotated[float, typer.Option(help="Simulated minutes of recording (after warm-up).")] = 3.0,
    seed: Annotated[int, typer.Option(help="Random seed: same seed, same traffic.")] = 0,
    lanes_per_direction: Annotated[int, typer.Option(min=2, max=3, help="2 or 3 lanes per direction.")] = 3,
    flow: Annotated[float | None, typer.Option(help="Inflow per direction [veh/h]; default: generator's.")] = None,
) -> None:
    """Simulate a straight two-direction highway in SUMO and write HighD-format recordings."""
    with user_errors(), progress_bar() as bar:
        task = bar.add_task("simulating", total=100.0)
        paths = generate_recordings(
            out,
            minutes=minutes,
            seed=seed,
            lanes_per_direction=lanes_per_direction,
            flow_veh_per_h=flow,
            progress=lambda frac: bar.update(task, completed=100.0 * frac),
        )
    console.print(f"wrote {len(paths)} recording(s) to {out}")


@app.command()
def scenarios(
    highd: Annotated[Path, typer.Option(help="Directory with NN_tracks.csv, NN_tracksMeta.csv, NN_recordingMeta.csv.")],
    out: Annotated[Path, typer.Option(help="Output scenario file (Arrow IPC, zstd; .parquet suffix: Parquet).")],
    max: Annotated[int | None, typer.Option("--max", help="Sample at most N scenarios (paper: 10,000).")] = None,
    seed: Annotated[int, typer.Option(help="Seed of the random sample.")] = 0,
    stride: Annotated[int, typer.Option(min=1, help="Sliding-window stride [frames].")] = DEFAULT_STRIDE_FRAMES,
    recordings: Annotated[str | None, typer.Option(help="Comma-separated recording ids (default: all).")] = None,
) -> None:
    """Cut recordings into 8 s ego-centric scenarios (3 s history, 5 s future) and store them."""
    with user_errors():
        recs = read_recordings(highd, _parse_ids(recordings))
        total = len(enumerate_windows(recs, stride))
        n = total if max is None else min(max, total)
        with progress_bar() as bar:
            task = bar.add_task("extracting", total=n)
            batch = extract_scenarios(
                recs, max_scenarios=max, seed=seed, stride_frames=stride,
                progress=lambda k: bar.advance(task, k),
            )
        provenance = {
            "source": str(highd), "recordings": [r.recording_id for r in recs], "stride_frames": stride,
            "max": max, "seed": seed, "windows_available": total,
        }
        save_scenarios(batch, out, extra_meta={"provenance": provenance})
    console.print(f"wrote {len(batch)} of {total} scenarios to {out}")


@app.command()
def info(
    scenarios_file: Annotated[Path, typer.Argument(help="A scenario file.")],
    as_json: Annotated[bool, typer.Option("--json", help="Machine-readable output.")] = False,
) -> None:
    """Summarise a scenario file: counts, recordings, neighbours, provenance."""
    with user_errors():
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
