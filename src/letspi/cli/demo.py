"""``letspi demo``: the main job on the embedded default (generated data)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from letspi.cli.common import console, progress_bar, user_errors


def demo(
    out: Annotated[Path, typer.Option(help="Working directory for all demo outputs.")] = Path("letspi-demo"),
    minutes: Annotated[float, typer.Option(help="Simulated minutes of traffic to generate.")] = 3.0,
    seed: int = 0,
    max_scenarios: Annotated[int, typer.Option(help="Scenarios to sample.")] = 2000,
) -> None:
    """Generate (or reuse) SUMO traffic in HighD format and extract planning scenarios."""
    from letspi.highd.io import list_recording_ids, read_recordings
    from letspi.scenario.extract import extract_scenarios
    from letspi.scenario.store import save_scenarios
    from letspi.sumo.generate import generate_recordings

    highd_dir = out / "highd"
    scenarios_file = out / "scenarios.parquet"
    with user_errors():
        if highd_dir.exists() and list_recording_ids(highd_dir):
            console.print(f"reusing recordings in {highd_dir}")
        else:
            with progress_bar() as bar:
                task = bar.add_task("simulating (SUMO)", total=100.0)
                generate_recordings(
                    highd_dir, minutes=minutes, seed=seed,
                    progress=lambda f: bar.update(task, completed=100.0 * f),
                )
        recs = read_recordings(highd_dir)
        with progress_bar() as bar:
            task = bar.add_task("extracting scenarios", total=None)
            batch = extract_scenarios(
                recs, max_scenarios=max_scenarios, seed=seed, progress=lambda k: bar.advance(task, k)
            )
        save_scenarios(batch, scenarios_file, extra_meta={"provenance": {"source": str(highd_dir), "seed": seed}})
    console.print(f"[green]{len(batch)} scenarios[/green] from {len(recs)} recording(s) -> {scenarios_file}")
