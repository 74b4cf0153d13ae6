"""Text panels of the reflection loop (the paper's Figs 4-5): per ``IterationRecord`` the safety analysis
report (left) and the LLM's response (right), wrapped and verbatim (no mathtext: ``$`` is literal)."""

from __future__ import annotations

import json
import math
import textwrap
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from matplotlib.axes import Axes
from matplotlib.text import Text

from letspi.viz import style

PANEL_FONT_SIZE = 8.5
#: average glyph width of DejaVu Sans as a fraction of the font size (for wrapping)
_CHAR_WIDTH_EM = 0.56
_LINE_SPACING = 1.3
#: longer texts are cut with a note saying how many lines were left out
MAX_LINES = 28

#: labels and units of metrics that commonly appear in ``IterationRecord.metrics``
METRIC_LABELS: dict[str, tuple[str, str]] = {
    "min_ttc_s": ("min TTC", "s"),
    "min_ttc2d_s": ("min 2-D TTC", "s"),
    "min_pet_s": ("min PET", "s"),
    "min_box_gap_m": ("min gap", "m"),
    "min_centre_dist_m": ("min distance", "m"),
    "max_drac_mps2": ("max DRAC", "m/s²"),
    "collision": ("collision", ""),
}


@dataclass(frozen=True)
class IterationRecord:
    """One reflection iteration, as the panels show it: ``iteration`` (0: the first plan), ``safety_report`` (the
    report handed to the LLM), the LLM's ``rationale`` and ``params`` (name -> value), ``lon_factor`` in [0, 1] and
    ``lane_factor`` in [-1, 1] (NaN: none), and the checked plan's ``metrics`` (units in the names)."""

    iteration: int
    safety_report: str
    rationale: str
    params: dict[str, float] = field(default_factory=dict)
    lon_factor: float = math.nan
    lane_factor: float = math.nan
    metrics: dict[str, float] = field(default_factory=dict)

    @classmethod
    def from_dict(cls, data: Mapping[str, object]) -> IterationRecord:
        """Build from a JSON-like mapping (missing optional fields take their defaults)."""
        def floats(key: str) -> dict[str, float]:
            raw = data.get(key) or {}
            if not isinstance(raw, Mapping):
                raise ValueError(f"IterationRecord.{key} must be a mapping, got {type(raw).__name__}")
            return {str(k): _to_float(v) for k, v in raw.items()}

        return cls(
            iteration=int(data["iteration"]),  # type: ignore[call-overload]
            safety_report=str(data.get("safety_report", "")),
            rationale=str(data.get("rationale", "")),
            params=floats("params"),
            lon_factor=_to_float(data.get("lon_factor")),
            lane_factor=_to_float(data.get("lane_factor")),
            metrics=floats("metrics"),
        )

    def to_dict(self) -> dict[str, object]:
        """JSON-ready dict (NaN factors become None)."""
        d = asdict(self)
        for key in ("lon_factor", "lane_factor"):
            if isinstance(d[key], float) and math.isnan(d[key]):
                d[key] = None
        return d


def _to_float(value: object) -> float:
    if value is None:
        return math.nan
    if isinstance(value, bool):
        return float(value)
    return float(value)  # type: ignore[arg-type]


def load_iterations(path: Path) -> list[IterationRecord]:
    """Read a JSON list of iteration records (``IterationRecord.to_dict`` shape), sorted by iteration."""
    raw = json.loads(Path(path).read_text())
    if isinstance(raw, Mapping):
        raw = raw.get("iterations", [])
    if not isinstance(raw, list):
        raise ValueError(f"{path}: expected a JSON list of iteration records")
    return sorted((IterationRecord.from_dict(r) for r in raw), key=lambda r: r.iteration)


def format_number(value: float, unit: str = "") -> str:
    """Compact number for panels: 3 significant digits, inf as '∞', NaN as 'n/a'."""
    if math.isnan(value):
        return "n/a"
    if math.isinf(value):
        text = "∞" if value > 0 else "-∞"
    else:
        text = f"{value:.3g}" if abs(value) < 1000 else f"{value:.0f}"
    return f"{text} {unit}".strip()


def format_metrics(metrics: Mapping[str, float]) -> str:
    """'min TTC 0.7 s · min PET 1.6 s · ...' with known labels/units, unknown keys verbatim."""
    parts = []
    for key, value in metrics.items():
        label, unit = METRIC_LABELS.get(key, (key, ""))
        if key == "collision":
            parts.append("collision" if value else "no collision")
        else:
            parts.append(f"{label} {format_number(float(value), unit)}")
    return " · ".join(parts)


def describe_adjustment(lon_factor: float, lane_factor: float) -> str:
    """The goal adjustment in words (see ``letspi.physics.goals.adjust_goals``)."""
    parts = []
    if math.isnan(lon_factor):
        parts.append("longitudinal: none")
    else:
        scale = 1.2 - 0.5 * min(max(lon_factor, 0.0), 1.0)
        parts.append(f"lon_factor {lon_factor:.2f} (goal distance ×{scale:.2f})")
    if math.isnan(lane_factor):
        parts.append("lane: none")
    else:
        side = "keep lane" if abs(lane_factor) < 1e-9 else ("towards left lane" if lane_factor < 0 else
                                                              "towards right lane")
        parts.append(f"lane_factor {lane_factor:+.2f} ({side})")
    return "; ".join(parts)


def wrap_text(text: str, width_chars: int, max_lines: int = MAX_LINES) -> str:
    """``text`` wrapped to ``width_chars`` (bullets keep a hanging indent), cut after ``max_lines`` with a note."""
    lines: list[str] = []
    for raw in text.strip().splitlines() or [""]:
        stripped = raw.lstrip()
        indent = raw[: len(raw) - len(stripped)]
        bullet = ""
        for mark in ("- ", "* ", "• "):
            if stripped.startswith(mark):
                bullet = mark
                break
        if not stripped:
            lines.append("")
            continue
        lines.extend(textwrap.wrap(
            stripped, width=max(10, width_chars), initial_indent=indent,
            subsequent_indent=indent + " " * len(bullet), break_long_words=True, break_on_hyphens=True,
        ))
    if len(lines) > max_lines:
        left_out = len(lines) - (max_lines - 1)
        lines = [*lines[: max_lines - 1], f"[… {left_out} more line(s) not shown]"]
    return "\n".join(lines)


def chars_per_line(width_in: float, font_size: float = PANEL_FONT_SIZE) -> int:
    """How many average characters fit a panel ``width_in`` inches wide (with inner padding)."""
    return max(20, int((width_in - 0.3) * 72.0 / (font_size * _CHAR_WIDTH_EM)))


def panel_texts(record: IterationRecord, width_chars: int) -> tuple[str, str]:
    """The wrapped (safety report, LLM response) texts of one iteration."""
    report = record.safety_report.strip() or "(no safety report)"
    left = report
    if record.metrics:
        left = f"Checked plan: {format_metrics(record.metrics)}\n\n{report}"
    right = [record.rationale.strip() or "(no rationale)", "",
             f"Goal adjustment: {describe_adjustment(record.lon_factor, record.lane_factor)}"]
    if record.params:
        right.append("Parameters: " + ", ".join(f"{k} = {format_number(v)}" for k, v in record.params.items()))
    return wrap_text(left, width_chars), wrap_text("\n".join(right), width_chars)


def text_height_in(text: str, font_size: float = PANEL_FONT_SIZE) -> float:
    """Height [in] a panel needs for ``text`` (title and padding included)."""
    n = text.count("\n") + 1
    return n * font_size * _LINE_SPACING / 72.0 + 0.4


def _text_panel(ax: Axes, title: str, text: str, edge: str, gid: str) -> Text:
    ax.set_xticks([])
    ax.set_yticks([])
    ax.grid(False)
    ax.set_facecolor(style.TEXT_BOX_FACE)
    for spine in ax.spines.values():
        spine.set_visible(True)
        spine.set_color(edge)
        spine.set_linewidth(1.6)
    ax.set_title(title, loc="left", color=edge, fontsize=style.BASE_FONT_SIZE)
    return ax.text(0.012, 0.97, text, transform=ax.transAxes, ha="left", va="top", fontsize=PANEL_FONT_SIZE,
                   family="DejaVu Sans", linespacing=_LINE_SPACING, parse_math=False, gid=gid, wrap=False)


def draw_iteration(ax_report: Axes, ax_response: Axes, record: IterationRecord, width_chars: int,
                   n_iterations: int | None = None) -> tuple[Text, Text]:
    """One iteration's safety report (left) and LLM response (right); gids ``safety_report:<i>``, ``rationale:<i>``."""
    left, right = panel_texts(record, width_chars)
    of = f" of {n_iterations - 1}" if n_iterations and n_iterations > 1 else ""
    label = "initial plan" if record.iteration == 0 else f"refinement {record.iteration}{of}"
    a = _text_panel(ax_report, f"Safety analysis report · iteration {record.iteration} ({label})", left,
                    style.ALERT, f"safety_report:{record.iteration}")
    b = _text_panel(ax_response, f"LLM response · iteration {record.iteration}", right, style.OKABE_ITO["blue"],
                    f"rationale:{record.iteration}")
    return a, b


def iterations_height_in(records: Sequence[IterationRecord], width_chars: int) -> list[float]:
    """Row height [in] of each iteration (the taller of its two panels)."""
    heights = []
    for r in records:
        left, right = panel_texts(r, width_chars)
        heights.append(max(text_height_in(left), text_height_in(right)))
    return heights


def panel_record(iteration: Any) -> IterationRecord:
    """A panel record from a ``letspi.method.reflection.IterationRecord`` (duck-typed: no import cycle)."""
    prop = iteration.proposal
    metrics = {k: float(v) for k, v in iteration.report.metrics.items()}
    return IterationRecord(iteration=int(iteration.iteration), safety_report=iteration.report.to_text(prop),
                           rationale=prop.rationale or "", params=dict(prop.params.as_dict()),
                           lon_factor=float(prop.lon_factor), lane_factor=float(prop.lane_factor), metrics=metrics)
