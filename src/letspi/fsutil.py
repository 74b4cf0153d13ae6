"""Crash-safe file writes and one writer per output.

Writes go to a temporary file beside the target, fsynced and renamed over it, then the directory is fsynced: a
reader sees the old or the new file. ``provenance_*`` record paths in manifests without the machine's directories.
"""

from __future__ import annotations

import fcntl
import json
import os
import re
import shlex
import time
import uuid
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any, TextIO

TMP_SUFFIX = ".tmp"


def _fsync_dir(directory: Path) -> None:
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:  # some filesystems do not open directories; the rename is still atomic
        return
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def atomic_write(path: Path, write: Callable[[Path], None]) -> Path:
    """Call ``write(tmp_path)`` and move the result to ``path`` atomically and durably."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{uuid.uuid4().hex[:8]}{TMP_SUFFIX}")
    try:
        write(tmp)
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    _fsync_dir(path.parent)
    return path


def atomic_write_text(path: Path, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically and durably."""
    def write(tmp: Path) -> None:
        tmp.write_text(text, encoding="utf-8")

    return atomic_write(path, write)


def remove_stale_temporaries(directory: Path) -> int:
    """Delete temporaries a killed writer left in ``directory``; returns how many."""
    n = 0
    for tmp in Path(directory).glob(f".*{TMP_SUFFIX}"):
        tmp.unlink(missing_ok=True)
        n += 1
    return n


def provenance_path(path: str | os.PathLike[str], root: str | os.PathLike[str] | None = None) -> str:
    """``path`` as a manifest records it: a relative path as given; an absolute one relative to ``root``
    (default: the working directory) when it lies below it, else by its file name alone."""
    text = os.fspath(path)
    if not os.path.isabs(text):
        return text
    base = os.path.abspath(os.fspath(root) if root is not None else os.getcwd())
    full = os.path.normpath(text)
    if base != os.path.dirname(base) and full.startswith(base.rstrip(os.sep) + os.sep):
        return os.path.relpath(full, base)
    return os.path.basename(full) or full


def _provenance_arg(arg: str) -> str:
    option, eq, value = arg.partition("=")
    if eq and option.startswith("-"):
        return f"{option}={_provenance_arg(value)}"
    return provenance_path(arg) if os.path.isabs(arg) else arg


def provenance_command(program: str, args: Sequence[str]) -> str:
    """The command line ``program args...`` as a manifest records it: absolute paths among the arguments
    (``--out /abs/dir`` or ``--out=/abs/dir``) through ``provenance_path``, each argument shell-quoted."""
    return " ".join([program, *(shlex.quote(_provenance_arg(a)) for a in args)])


#: an absolute path inside a text: a word that starts with "/" (after a space, "=" or the text's start)
_ABSOLUTE_WORD = re.compile(r"(?<![^\s=])/[^\s'\"]+")


def provenance_record(value: Any) -> Any:
    """``value`` (dicts, lists, strings, paths, numbers) with every absolute path in it through ``provenance_path``: a
    ``Path``, a string that is one, or a word of a text that is one (such as a command line)."""
    if isinstance(value, dict):
        return {k: provenance_record(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [provenance_record(v) for v in value]
    if isinstance(value, str | os.PathLike) and os.path.isabs(value):
        return provenance_path(value)
    if isinstance(value, str):
        return _ABSOLUTE_WORD.sub(lambda m: provenance_path(m.group(0)), value)
    return value


SETTINGS_FILE = "settings.json"


def resume_directory(out: Path, settings: Mapping[str, Any], *, what: str, instead: str,
                     parts_dir: str = "parts") -> tuple[Path, bool]:
    """Prepare the output ``out`` of a resumable run that stores its work in ``out/parts_dir`` (both created, a killed
    writer's temporaries removed; ``settings.json`` pins what a rerun must match). Returns (the parts directory,
    True on a fresh start); a rerun with other settings gets a ``ValueError`` naming the changed keys, untouched."""
    out = Path(out)
    parts = out / parts_dir
    parts.mkdir(parents=True, exist_ok=True)
    remove_stale_temporaries(parts)
    remove_stale_temporaries(out)
    settings_file = out / SETTINGS_FILE
    if settings_file.exists():
        old = json.loads(settings_file.read_text())
        if old != settings:
            changed = sorted(k for k in settings if old.get(k) != settings[k])
            raise ValueError(f"{out}: holds {what} made with other settings ({', '.join(changed)}); {instead} "
                             "or delete it")
        return parts, False
    atomic_write_text(settings_file, json.dumps(settings, indent=2, sort_keys=True) + "\n")
    return parts, True


class OutputLockedError(OSError):
    """Another live process holds the writer lock of an output (``writer_lock``)."""


#: the lock file inside a locked directory (a locked file's lock is ``.NAME.lock`` beside it)
DIRECTORY_LOCK = ".letspi-writer.lock"


def lock_file_of(output: Path, *, directory: bool) -> Path:
    """Where the writer lock of ``output`` lives: inside a directory (its parent may be read-only),
    beside a file (``.NAME.lock``)."""
    output = Path(output)
    return output / DIRECTORY_LOCK if directory else output.with_name(f".{output.name}.lock")


def _holder(lock: Path) -> dict[str, object]:
    try:
        data = json.loads(lock.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


def _acquire(lock: Path, output: Path) -> TextIO:
    """The open, flock-ed lock file (``OutputLockedError`` naming the holder when another has it)."""
    while True:
        try:
            fh = open(lock, "a+", encoding="utf-8")  # held until release
        except OSError as exc:  # name the output, not our lock file
            raise OSError(exc.errno, exc.strerror, str(output)) from exc
        try:
            fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            fh.close()
            holder = _holder(lock)
            what = f" ({holder['command']})" if holder.get("command") else ""
            raise OutputLockedError(f"{output} is being written by process {holder.get('pid', '?')}{what}; wait for "
                                    "it to finish or write elsewhere") from None
        try:  # the previous holder may have removed the file between our open and flock: retry on a new one
            if os.fstat(fh.fileno()).st_ino == os.stat(lock).st_ino:
                return fh
        except FileNotFoundError:
            pass
        fh.close()


@contextmanager
def writer_lock(output: Path, command: str = "", *, directory: bool = True) -> Iterator[Path]:
    """Hold the exclusive writer lock (an ``flock``, released by the kernel when its holder dies) of ``output``, a
    results directory (created if missing) or a file such as a memory bank (``directory=False``). Another process
    gets ``OutputLockedError`` at once, naming the holder's pid; on release the lock file goes, and so does a
    directory this call created if nothing was written into it."""
    output = Path(output)
    created = directory and not output.exists()
    if directory:
        output.mkdir(parents=True, exist_ok=True)
    else:
        output.parent.mkdir(parents=True, exist_ok=True)
    lock = lock_file_of(output, directory=directory)
    fh = _acquire(lock, output)
    try:
        fh.seek(0)
        fh.truncate()
        fh.write(json.dumps({"pid": os.getpid(), "command": command,
                             "started": time.strftime("%Y-%m-%dT%H:%M:%S")}) + "\n")
        fh.flush()
        yield lock
    finally:
        lock.unlink(missing_ok=True)  # while still locked: an opener of the old file retries on a new one
        fh.close()
        if created and output.is_dir() and not any(output.iterdir()):
            output.rmdir()
