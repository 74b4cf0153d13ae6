"""One table over several suites' leaderboards (``letspi benchmark summary``), read from ``leaderboard.json``; a
planner is dominated when another (not ``human``) has both CR-at-fault and SR intervals wholly better."""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Final

#: planners that are not baselines to compare with (the recorded human future)
NOT_COMPARED: Final = frozenset({"human"})


def load_boards(results: Sequence[Path]) -> list[dict[str, Any]]:
    """The ``leaderboard.json`` of each results directory, in the order given."""
    boards = []
    for directory in results:
        path = directory / "leaderboard.json"
        if not path.is_file():
            raise ValueError(f"{path}: no leaderboard here (run `letspi benchmark run SUITE --out {directory}`)")
        boards.append(json.loads(path.read_text()))
    return boards


def columns(boards: Sequence[Mapping[str, Any]]) -> list[tuple[str, str, Mapping[str, Any]]]:
    """(suite name, mode slug, mode board) for every mode of every board, open loop first; boards of one suite id
    share a column (each planner's paired statistics stay those of its own run)."""
    merged: dict[tuple[str, str], dict[str, Any]] = {}
    names: dict[tuple[str, str], str] = {}
    for board in boards:
        for slug in sorted(board["modes"], key=lambda s: (s != "open-loop", s)):
            mode, key = board["modes"][slug], (board["suite"], slug)
            names[key] = board["definition"]["name"]
            if key not in merged:
                merged[key] = {"n_windows": mode["n_windows"], "planners": dict(mode["planners"]),
                               "paired": {"reference": mode["paired"]["reference"],
                                          "planners": dict(mode["paired"]["planners"])}}
                continue
            into = merged[key]
            if into["n_windows"] != mode["n_windows"] or into["paired"]["reference"] != mode["paired"]["reference"]:
                raise ValueError(f"{board['suite']} {slug}: two runs with different windows or references")
            into["planners"].update(mode["planners"])
            into["paired"]["planners"].update(mode["paired"]["planners"])
    return [(names[key], key[1], mode) for key, mode in merged.items()]


def planner_order(boards: Sequence[Mapping[str, Any]]) -> list[str]:
    """Every planner of any board, in the order of first appearance."""
    seen: dict[str, None] = {}
    for _, _, mode in columns(boards):
        for name in mode["planners"]:
            seen.setdefault(name, None)
    return list(seen)


def cell(mode: Mapping[str, Any], planner: str) -> str:
    """``CR at fault (CI), p vs reference · SR`` of one planner in one mode, or "–"."""
    row = mode["planners"].get(planner)
    if row is None:
        return "–"
    low, high = row["cr_at_fault_pct_ci95"]
    text = f"{row['cr_at_fault_pct']:.2f} ({low:.2f}–{high:.2f})"
    paired = mode["paired"]["planners"].get(planner)
    if paired is not None:
        text += f" p {paired['cr_at_fault_pct']['p_mcnemar']:.2g}"
    return text + f" · {row['sr_pct']:.1f}"


def dominated_by(mode: Mapping[str, Any], planner: str) -> list[str]:
    """The planners whose CR-at-fault interval is wholly below ``planner``'s and SR interval wholly above, here."""
    rows = mode["planners"]
    me = rows.get(planner)
    if me is None:
        return []
    return [name for name, other in rows.items()
            if name != planner and name not in NOT_COMPARED
            and other["cr_at_fault_pct_ci95"][1] < me["cr_at_fault_pct_ci95"][0]
            and other["sr_pct_ci95"][0] > me["sr_pct_ci95"][1]]


def summary_markdown(boards: Sequence[Mapping[str, Any]], planners: Sequence[str] | None = None,
                     modes: Sequence[str] | None = None) -> str:
    """The headline table (planners x suite modes, or only ``modes``) and a line per dominated planner."""
    cols = [c for c in columns(boards) if not modes or c[1] in modes]
    if not cols:
        raise ValueError(f"no leaderboard has a mode {', '.join(modes or [])}")
    names = list(planners) if planners else planner_order(boards)
    one_mode = len({slug for _, slug, _ in cols}) == 1
    header = ["planner", *[f"{suite}{'' if one_mode else ' ' + slug} (n {mode['n_windows']})"
                           for suite, slug, mode in cols]]
    lines = ["| " + " | ".join(header) + " |", "|---|" + "---|" * len(cols)]
    lines += ["| " + " | ".join([name, *[cell(mode, name) for _, _, mode in cols]]) + " |" for name in names]
    notes = [f"{name} is dominated on {suite} {slug} by {', '.join(others)}"
             for suite, slug, mode in cols for name in names if name not in NOT_COMPARED
             for others in [dominated_by(mode, name)] if others]
    lines += ["", "Cells: CR at fault % (95 % CI), exact McNemar p against the suite's reference (sf) on the same "
              "windows, · SR %."]
    lines += ["Dominated (both intervals apart): " + ("; ".join(notes) if notes else "none") + "."]
    suites = ", ".join(dict.fromkeys(f"`{board['suite']}`" for board in boards))
    lines += [f"Suites: {suites}."]
    return "\n".join(lines) + "\n"
