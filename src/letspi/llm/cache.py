"""Persistent LLM response cache: SQLite in WAL mode, safe for concurrent threads and processes.

The key hashes the backend identity (``backend_identity``), the messages, the decoding settings and the
schema, so a rerun at temperature 0 replays identical replies. Every transport success is stored, parse
failures included (the retry's different messages give a different key). Location:
``$LETSPI_CACHE_DIR/llm_cache.sqlite`` (default ``~/.cache/letspi``); any failure to use it raises
``ResponseCacheError`` naming the file.
"""

from __future__ import annotations

import hashlib
import json
import os
import sqlite3
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

from letspi.llm.types import DecodingSettings, KeyedBackend, Message, ResponseCacheError

#: Bump when the key recipe or the stored columns change meaning.
CACHE_FORMAT_VERSION: Final = 1
CACHE_FILENAME: Final = "llm_cache.sqlite"

_SCHEMA_SQL: Final = """
CREATE TABLE IF NOT EXISTS responses (
    key TEXT PRIMARY KEY,
    model_spec TEXT NOT NULL,
    text TEXT NOT NULL,
    prompt_tokens INTEGER NOT NULL,
    completion_tokens INTEGER NOT NULL,
    latency_s REAL NOT NULL,
    created_unix REAL NOT NULL
)
"""


def default_cache_dir() -> Path:
    """``$LETSPI_CACHE_DIR`` or ``~/.cache/letspi``."""
    env = os.environ.get("LETSPI_CACHE_DIR")
    return Path(env).expanduser() if env else Path.home() / ".cache" / "letspi"


def backend_identity(backend: Any) -> str:
    """What a reply depends on besides the request: the backend's ``cache_identity`` (the embedded backend:
    weights, adapter, runtime) when it has one, else its spec."""
    return str((backend.cache_identity if isinstance(backend, KeyedBackend) else None) or backend.spec)


def cache_key(model_spec: str, messages: Sequence[Message], settings: DecodingSettings,
              schema: dict[str, Any] | None) -> str:
    """Stable hash of everything that determines a reply."""
    payload = {
        "v": CACHE_FORMAT_VERSION,
        "spec": model_spec,
        "messages": [{"role": m["role"], "content": m["content"]} for m in messages],
        "settings": settings.as_dict(),
        "schema": schema,
    }
    blob = json.dumps(payload, sort_keys=True, ensure_ascii=False, separators=(",", ":"))
    return hashlib.sha256(blob.encode("utf-8")).hexdigest()


@dataclass(frozen=True)
class CachedEntry:
    """One stored reply: the raw text plus the original call's cost."""

    text: str
    prompt_tokens: int
    completion_tokens: int
    latency_s: float


class ResponseCache:
    """Key -> reply store, one connection per thread; processes serialise on SQLite's lock (busy timeout),
    and a duplicate write of a key is harmless (``INSERT OR REPLACE``)."""

    def __init__(self, path: str | Path | None = None, *, busy_timeout_s: float = 30.0) -> None:
        self.path = Path(path) if path is not None else default_cache_dir() / CACHE_FILENAME
        self.busy_timeout_s = busy_timeout_s
        self._local = threading.local()
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise self._error(exc) from None
        self._connect()  # create the table now so configuration errors surface early

    def _error(self, exc: BaseException) -> ResponseCacheError:
        return ResponseCacheError(
            f"{self.path}: the LLM response cache cannot be used ({exc}); delete the file (it only "
            "caches replies), free disk space, or point LETSPI_CACHE_DIR elsewhere"
        )

    def _connect(self) -> sqlite3.Connection:
        conn: sqlite3.Connection | None = getattr(self._local, "conn", None)
        if conn is None:
            try:
                conn = sqlite3.connect(self.path, timeout=self.busy_timeout_s, isolation_level=None)
                conn.execute("PRAGMA journal_mode=WAL")
                conn.execute("PRAGMA synchronous=NORMAL")  # durable enough for a cache, much faster
                conn.execute(_SCHEMA_SQL)
            except (sqlite3.Error, OSError) as exc:
                raise self._error(exc) from None
            self._local.conn = conn
        return conn

    def _execute(self, sql: str, params: tuple[Any, ...] = ()) -> sqlite3.Cursor:
        try:
            return self._connect().execute(sql, params)
        except (sqlite3.Error, OSError) as exc:
            raise self._error(exc) from None

    def get(self, key: str) -> CachedEntry | None:
        sql = "SELECT text, prompt_tokens, completion_tokens, latency_s FROM responses WHERE key = ?"
        try:
            row = self._execute(sql, (key,)).fetchone()
        except sqlite3.Error as exc:
            raise self._error(exc) from None
        if row is None:
            return None
        return CachedEntry(text=row[0], prompt_tokens=row[1], completion_tokens=row[2], latency_s=row[3])

    def put(self, key: str, model_spec: str, entry: CachedEntry) -> None:
        self._execute("INSERT OR REPLACE INTO responses VALUES (?, ?, ?, ?, ?, ?, ?)",
                      (key, model_spec, entry.text, entry.prompt_tokens, entry.completion_tokens, entry.latency_s,
                       time.time()))

    def __len__(self) -> int:
        return int(self._execute("SELECT COUNT(*) FROM responses").fetchone()[0])

    def clear(self) -> None:
        self._execute("DELETE FROM responses")

    def close(self) -> None:
        """Close this thread's connection (other threads' connections close when collected)."""
        conn = getattr(self._local, "conn", None)
        if conn is not None:
            conn.close()
            self._local.conn = None
