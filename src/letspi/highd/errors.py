"""Errors raised when a HighD recording (on disk or in memory) does not follow the format."""

from __future__ import annotations

from pathlib import Path


class HighDFormatError(ValueError):
    """A HighD file or in-memory :class:`~letspi.highd.types.Recording` violates the format.

    Attributes:
        path: the offending file. For a recording validated in memory (before writing), the path
            of the file the data would be written to.
        column: the offending HighD column name, if the problem is tied to one column.
        line: 1-based line number in the CSV file, counting the header as line 1 (so the first
            data row is line 2). For an in-memory recording it is the line the row would occupy
            in the written file (rows sorted by (id, frame) for tracks). ``None`` when the problem
            is not tied to one line (missing file, missing column, ...).
        reason: the bare description of the problem, without the location prefix.

    The message reads ``<file name>: column '<col>', line <n>: <reason>`` with the parts that are
    known, e.g. ``01_tracks.csv: column 'xVelocity', line 17: not a number ('abc')``.
    """

    def __init__(
        self,
        path: Path | str,
        reason: str,
        *,
        column: str | None = None,
        line: int | None = None,
        row: int | None = None,
    ) -> None:
        self.path = Path(path)
        self.column = column
        self.line = line if line is not None else row  # ``row=`` is accepted as an alias
        self.reason = reason
        super().__init__(self._format())

    def __reduce__(self) -> tuple[object, ...]:
        # keep the exception picklable (multiprocessing) despite the keyword-only fields
        return (_rebuild, (self.path, self.reason, self.column, self.line))

    @property
    def row(self) -> int | None:
        """Alias of :attr:`line` (1-based CSV line number, header = line 1)."""
        return self.line

    def _format(self) -> str:
        location = [f"column '{self.column}'"] if self.column is not None else []
        if self.line is not None:
            location.append(f"line {self.line}")
        prefix = f"{self.path.name}: "
        if location:
            prefix += ", ".join(location) + ": "
        return prefix + self.reason


def _rebuild(path: Path, reason: str, column: str | None, line: int | None) -> HighDFormatError:
    return HighDFormatError(path, reason, column=column, line=line)
