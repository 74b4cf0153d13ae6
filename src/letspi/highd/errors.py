"""Errors raised when a HighD recording (on disk or in memory) does not follow the format."""

from __future__ import annotations

from pathlib import Path


class HighDFormatError(ValueError):
    """A HighD file or in-memory ``Recording`` violates the format.

    ``path``: the offending file (in memory: the file the data would be written to); ``column``: the HighD column,
    if any; ``line``: 1-based CSV line, header = line 1 (in memory: the line the row would occupy, tracks sorted by
    (id, frame)), None when not tied to a line; ``reason``: the bare problem. The message reads e.g.
    ``01_tracks.csv: column 'xVelocity', line 17: not a number ('abc')``, with the parts that are known."""

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
        """Alias of ``line``."""
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
