"""``letspi export``: scenarios (and planners' plans) in other tools' formats."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import numpy as np
import typer

from letspi.cli.common import console, user_errors
from letspi.evaluation.results import load_plans
from letspi.scenario.store import count_scenarios, load_scenarios

app = typer.Typer(help="Export scenarios and plans to other tools' formats.", no_args_is_help=True,
                  rich_markup_mode=None)

EXTRA_HINT = 'pip install -e "packages/letspi-interop[commonroad]"'


@app.command("commonroad")
def commonroad_cmd(
    scenarios: Annotated[Path, typer.Option(help="Scenario file (from `letspi data scenarios`).")],
    out: Annotated[Path, typer.Option(help="Output directory: <scenario id>.xml and, with --results, "
                                           "<scenario id>.<planner>.solution.xml.")],
    limit: Annotated[int | None, typer.Option(help="Only the first N scenarios.")] = None,
    index: Annotated[list[int] | None, typer.Option(help="Only these scenario indices (repeatable).")] = None,
    results: Annotated[Path | None, typer.Option(help="An evaluation results directory whose plans to export.")] = None,
    planner: Annotated[list[str] | None, typer.Option(help="Planner(s) of --results whose plans to export "
                                                           "(default: all stored).")] = None,
    orientation: Annotated[str, typer.Option(help="heading (atan2(vy, vx), a vehicle's yaw) or axis_aligned "
                                                  "(0: letspi's own box geometry).")] = "heading",
) -> None:
    """Export scenarios as CommonRoad scenario files. Lanelets from the lane markings, neighbours and context
    vehicles as dynamic obstacles with their recorded futures, the ego as the planning problem; optionally
    a planner's plans as CommonRoad solutions (needs the `commonroad` extra)."""
    with user_errors():
        try:
            import letspi_interop.commonroad as cr
        except ImportError as exc:
            raise ValueError(f"letspi export commonroad needs the optional extra commonroad-io: {EXTRA_HINT} "
                             f"({exc})") from None
        if orientation not in cr.ORIENTATIONS:
            raise ValueError(f"--orientation must be one of {', '.join(cr.ORIENTATIONS)}, got {orientation!r}")
        n = count_scenarios(scenarios)
        if index:
            bad = [i for i in index if not 0 <= i < n]
            if bad:
                raise ValueError(f"--index {bad[0]} outside 0..{n - 1} ({scenarios} holds {n} scenarios)")
            rows = np.array(sorted(set(index)))
        else:
            rows = np.arange(n if limit is None else min(limit, n))
        batch = load_scenarios(scenarios, rows)
        plans: dict[str, dict[str, tuple[np.ndarray, np.ndarray]]] = {}
        if results is not None:
            names = planner or sorted(p.name for p in (results / "per_scenario").iterdir() if p.is_dir())
            for name in names:
                stored = load_plans(results, name)
                if not stored:
                    raise ValueError(f"{results}: no stored plans of planner {name!r}")
                plans[name] = {sid: (xy, vxy) for sid, (xy, vxy, _) in stored.items()}
        elif planner:
            raise ValueError("--planner selects plans of --results; give the results directory too")
        written = cr.export(batch, out, plans=plans, orientation=orientation)  # type: ignore[arg-type]
    n_solutions = sum(p.name.endswith(".solution.xml") for p in written)
    console.print(f"wrote {len(written) - n_solutions} scenario files and {n_solutions} solution files to {out}/")
