"""Progress when stderr is not a terminal: plain, unwrapped lines at a modest rate (``LineProgress``)."""

from __future__ import annotations

import io

from rich.console import Console

from letspi.cli.common import LineProgress, progress_bar, run_progress
from letspi.execution.ordered import RunStatus


def _console(width: int = 30) -> tuple[Console, io.StringIO]:
    out = io.StringIO()
    return Console(file=out, width=width, force_terminal=False), out


def test_lines_never_wrap_and_the_last_one_says_done() -> None:
    con, out = _console()
    with LineProgress(con, interval_s=0.0) as bar:
        task = bar.add_task("memory collection (llamacpp:smollm2-135m-letspi)", total=8)
        for _ in range(8):
            bar.advance(task, 1)
    lines = out.getvalue().splitlines()
    assert len(lines) == 8  # one per update at interval 0, each whole on one line despite width 30
    assert all(line.startswith("memory collection (llamacpp:smollm2-135m-letspi): ") for line in lines)
    assert lines[-1].startswith("memory collection (llamacpp:smollm2-135m-letspi): 8/8 (100 %)")
    assert "ETA" in lines[0] and "ETA" not in lines[-1]


def test_updates_are_rate_limited_but_completion_is_always_printed() -> None:
    con, out = _console(200)
    with LineProgress(con, interval_s=3600.0) as bar:
        task = bar.add_task("extracting", total=1000)
        for _ in range(999):
            bar.advance(task, 1)
        assert out.getvalue() == ""  # nothing within the interval
        bar.update(task, completed=1000)
        other = bar.add_task("fine-tuning", total=None)
        bar.update(other, completed=3, description="fine-tuning (loss 0.5)")
    lines = out.getvalue().splitlines()
    assert lines[0].startswith("extracting: 1000/1000 (100 %)")
    assert lines[1].startswith("fine-tuning (loss 0.5): 3,")  # unfinished tasks get a last line at exit


def test_a_concurrent_runs_status_is_shown_in_the_line() -> None:
    con, out = _console(200)
    with LineProgress(con, interval_s=0.0) as bar:
        update = run_progress(bar, bar.add_task("letspi-fast", total=10))
        update(4, RunStatus(done=4, total=10, written=4, failed=0, fallbacks=1, running=1, requests_in_flight=1,
                            elapsed_s=8.0))
    assert out.getvalue().strip() == ("letspi-fast: 4/10 (40 %), 0.50 scenarios/s, 1 fallbacks, 0 failed, "
                                      "ETA 0:00:12")


def test_without_a_terminal_the_commands_get_plain_lines() -> None:
    assert isinstance(progress_bar(), LineProgress)  # pytest captures stderr: not a terminal
