"""The memory bank: validated driving experiences on SQLite (paper §III-E, "Scenario-based Memory").

One row per (scenario content digest, collection configuration key). A fallback result is stored flagged, never
retrieved, not ``has``, and replaced when a resumed run retries it; a real row is never overwritten. WAL journal
with ``synchronous=FULL`` (a committed experience survives a kill and a power loss); non-finite metric floats
are stored as ``"inf"``/``"-inf"``/``"nan"`` (JSON has no infinity).
"""

from __future__ import annotations

import hashlib
import json
import math
import sqlite3
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, Final, Literal

import numpy as np

from letspi.arrays import Rows
from letspi.method.reflection import ReflectionResult
from letspi.physics.params import PARAM_NAMES, SocialForceParams
from letspi.scenario.features import FEATURE_NAMES, scenario_features
from letspi.scenario.types import ScenarioBatch

SCHEMA_VERSION: Final = 2
Synchronous = Literal["FULL", "NORMAL"]

_FEATURE_COLS: Final = tuple(FEATURE_NAMES)
_PARAM_COLS: Final = tuple(PARAM_NAMES)
_IDENTITY_COLS: Final = ("scenario_id", "scenario_digest", "recording_key", "recording_id", "ego_id", "frame0")
_DATA_COLS: Final = (
    *_IDENTITY_COLS, "config_key", *_FEATURE_COLS, *_PARAM_COLS, "lon_factor", "lane_factor",
    "metrics_before", "metrics_after", "n_iterations", "iterations", "model", "prompt", "reply", "rationale",
    "validated", "fallback", "created_at",
)
_SELECT_COLS: Final = ("id", *_DATA_COLS)

_SCHEMA: Final = f"""
CREATE TABLE IF NOT EXISTS schema_version (version INTEGER NOT NULL);
CREATE TABLE IF NOT EXISTS experiences (
    id INTEGER PRIMARY KEY,
    scenario_id TEXT NOT NULL,
    scenario_digest TEXT NOT NULL,
    recording_key TEXT NOT NULL,
    recording_id INTEGER NOT NULL,
    ego_id INTEGER NOT NULL,
    frame0 INTEGER NOT NULL,
    config_key TEXT NOT NULL,
    {", ".join(f"{c} REAL NOT NULL" for c in _FEATURE_COLS)},
    {", ".join(f"{c} REAL NOT NULL" for c in _PARAM_COLS)},
    lon_factor REAL NOT NULL,
    lane_factor REAL NOT NULL,
    metrics_before TEXT NOT NULL,
    metrics_after TEXT NOT NULL,
    n_iterations INTEGER NOT NULL,
    iterations TEXT NOT NULL,
    model TEXT NOT NULL,
    prompt TEXT,
    reply TEXT,
    rationale TEXT NOT NULL,
    validated INTEGER NOT NULL CHECK (validated IN (0, 1)),
    fallback INTEGER NOT NULL CHECK (fallback IN (0, 1)),
    created_at TEXT NOT NULL,
    UNIQUE (scenario_digest, config_key),
    CHECK (NOT (validated = 1 AND fallback = 1))
);
CREATE INDEX IF NOT EXISTS experiences_config ON experiences (config_key, validated, fallback);
CREATE TABLE IF NOT EXISTS datasets (
    digest TEXT PRIMARY KEY,
    path TEXT NOT NULL,
    n_scenarios INTEGER NOT NULL,
    first_seen TEXT NOT NULL
);
"""


# JSON with non-finite floats ----------------------------------------------------------------


def _json_safe(value: Any) -> Any:
    """Recursively: non-finite floats -> "inf"/"-inf"/"nan", NumPy scalars/arrays -> Python."""
    if isinstance(value, np.ndarray):
        return _json_safe(value.tolist())
    if isinstance(value, np.generic):
        return _json_safe(value.item())
    if isinstance(value, float) and not math.isfinite(value):
        return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf")
    if isinstance(value, dict):
        return {str(k): _json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_json_safe(v) for v in value]
    return value


def dumps(value: Any) -> str:
    """JSON text with non-finite floats as strings (strict JSON: SQLite's JSON functions can read it)."""
    return json.dumps(_json_safe(value), allow_nan=False, ensure_ascii=False)


_NON_FINITE: Final = {"inf": math.inf, "-inf": -math.inf, "nan": math.nan}


def decode_metrics(metrics: dict[str, Any]) -> dict[str, Any]:
    """A flat metrics dict read from JSON: "inf"/"-inf"/"nan" strings back to floats."""
    return {k: _NON_FINITE.get(v, v) if isinstance(v, str) else v for k, v in metrics.items()}


def _decode_iterations(records: list[dict[str, Any]]) -> list[dict[str, Any]]:
    out = []
    for rec in records:
        rec = dict(rec)
        if isinstance(rec.get("metrics"), dict):
            rec["metrics"] = decode_metrics(rec["metrics"])
        if isinstance(rec.get("violations"), list):
            rec["violations"] = [decode_metrics(v) for v in rec["violations"]]
        out.append(rec)
    return out


# Data ---------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Experience:
    """One stored experience: scenario (content digest) and vehicle, the 6 finite matching ``features``
    (``FEATURE_NAMES`` order), the final proposal, ``SafetyReport.metrics`` of the first and final iteration,
    every iteration's record; ``validated`` (safe, from the model) excludes ``fallback``; ``id``, ``created_at``:
    set by the bank (ignored by equality). ``ValueError`` for non-finite features."""

    scenario_id: str
    scenario_digest: str
    recording_key: str
    recording_id: int
    ego_id: int
    frame0: int
    config_key: str
    features: tuple[float, ...]
    params: SocialForceParams
    lon_factor: float
    lane_factor: float
    metrics_before: dict[str, Any]
    metrics_after: dict[str, Any]
    iterations: list[dict[str, Any]]
    model: str
    prompt: str | None
    reply: str | None
    rationale: str
    validated: bool
    fallback: bool = False
    id: int | None = field(default=None, compare=False)
    created_at: str | None = field(default=None, compare=False)

    def __post_init__(self) -> None:
        if len(self.features) != len(_FEATURE_COLS):
            raise ValueError(f"expected {len(_FEATURE_COLS)} features, got {len(self.features)}")
        bad = [n for n, f in zip(_FEATURE_COLS, self.features, strict=True) if not math.isfinite(f)]
        if bad:
            raise ValueError(f"scenario {self.scenario_id}: matching feature(s) {', '.join(bad)} not finite "
                             f"({dict(zip(_FEATURE_COLS, self.features, strict=True))})")
        if self.validated and self.fallback:
            raise ValueError(f"scenario {self.scenario_id}: a fallback result cannot be validated")

    @property
    def n_iterations(self) -> int:
        return len(self.iterations)

    @classmethod
    def from_reflection(cls, result: ReflectionResult, scenario: ScenarioBatch, *, scenario_digest: str,
                        config_key: str, model: str) -> Experience:
        """The experience of a reflection run on ``scenario`` (a batch of one): the final iteration's
        proposal, every iteration recorded; a final fallback proposal is flagged and not validated."""
        final = result.final.proposal
        features = scenario_features(scenario)[0]
        return cls(
            scenario_id=result.scenario_id, scenario_digest=scenario_digest, config_key=config_key,
            recording_key=str(scenario.recording_key[0]), recording_id=int(scenario.recording_id[0]),
            ego_id=int(scenario.ego_id[0]), frame0=int(scenario.frame0[0]),
            features=tuple(float(f) for f in np.asarray(features, dtype=np.float64).reshape(-1)),
            params=final.params, lon_factor=float(final.lon_factor), lane_factor=float(final.lane_factor),
            metrics_before=dict(result.metrics_before), metrics_after=dict(result.metrics_after),
            iterations=[rec.to_dict() for rec in result.iterations], model=model, prompt=final.prompt,
            reply=final.reply, rationale=final.rationale, validated=result.validated and not final.fallback,
            fallback=final.fallback)


@dataclass(frozen=True)
class MemoryFeatures(Rows):
    """Retrieval view of M rows, ascending id: ids (M,) int64, features (M, 6) float64 (``FEATURE_NAMES``
    order), and the vehicle of each memory: recording_key (M,) str, ego_id (M,) int64, frame0 (M,) int64."""

    ids: np.ndarray
    features: np.ndarray
    recording_key: np.ndarray
    ego_id: np.ndarray
    frame0: np.ndarray


def _row_values(exp: Experience, created_at: str) -> tuple[Any, ...]:
    return (
        exp.scenario_id, exp.scenario_digest, exp.recording_key, int(exp.recording_id), int(exp.ego_id),
        int(exp.frame0), exp.config_key, *(float(f) for f in exp.features),
        *(float(getattr(exp.params, p)) for p in _PARAM_COLS), float(exp.lon_factor), float(exp.lane_factor),
        dumps(exp.metrics_before), dumps(exp.metrics_after), exp.n_iterations, dumps(exp.iterations),
        exp.model, exp.prompt, exp.reply, exp.rationale, int(bool(exp.validated)), int(bool(exp.fallback)),
        created_at,
    )


def _from_row(row: Sequence[Any]) -> Experience:
    r = dict(zip(_SELECT_COLS, row, strict=True))
    return Experience(
        scenario_id=r["scenario_id"], scenario_digest=r["scenario_digest"], recording_key=r["recording_key"],
        recording_id=int(r["recording_id"]), ego_id=int(r["ego_id"]), frame0=int(r["frame0"]),
        config_key=r["config_key"], features=tuple(float(r[c]) for c in _FEATURE_COLS),
        params=SocialForceParams(**{p: float(r[p]) for p in _PARAM_COLS}), lon_factor=float(r["lon_factor"]),
        lane_factor=float(r["lane_factor"]), metrics_before=decode_metrics(json.loads(r["metrics_before"])),
        metrics_after=decode_metrics(json.loads(r["metrics_after"])),
        iterations=_decode_iterations(json.loads(r["iterations"])), model=r["model"], prompt=r["prompt"],
        reply=r["reply"], rationale=r["rationale"], validated=bool(r["validated"]), fallback=bool(r["fallback"]),
        id=int(r["id"]), created_at=r["created_at"])


def _now() -> str:
    return datetime.now(UTC).isoformat(timespec="milliseconds")


def _sample_rank(seed: int, scenario_digest: str, config_key: str) -> bytes:
    return hashlib.blake2b(f"{seed}\x1f{scenario_digest}\x1f{config_key}".encode(), digest_size=8).digest()


# The bank -----------------------------------------------------------------------------------


def _where(validated_only: bool, config_key: str | None) -> tuple[str, tuple[Any, ...]]:
    clauses, args = [], []
    if validated_only:
        clauses.append("validated = 1 AND fallback = 0")
    if config_key is not None:
        clauses.append("config_key = ?")
        args.append(config_key)
    return (" WHERE " + " AND ".join(clauses)) if clauses else "", tuple(args)


class MemoryBankError(ValueError):
    """A memory bank file that cannot be used (wrong schema version, not a bank)."""


class MemoryBank:
    """SQLite-backed experience store (``MemoryBank.open(path)``): one connection, used by one thread at a time;
    every process opens its own bank."""

    def __init__(self, conn: sqlite3.Connection, path: Path, *, readonly: bool) -> None:
        self._conn = conn
        self.path = path
        self.readonly = readonly
        self._own_writes = 0
        self._cache: dict[tuple[bool, str | None], tuple[tuple[int, int], MemoryFeatures]] = {}

    @classmethod
    def open(cls, path: str | Path, *, readonly: bool = False, synchronous: Synchronous = "FULL",
             timeout_s: float = 60.0) -> MemoryBank:
        """Open (creating if needed, unless ``readonly``) the bank at ``path``."""
        p = Path(path)
        if readonly:
            conn = sqlite3.connect(f"{p.resolve().as_uri()}?mode=ro", uri=True, timeout=timeout_s,
                                   isolation_level=None, check_same_thread=False)
        else:
            p.parent.mkdir(parents=True, exist_ok=True)
            # isolation_level=None: autocommit; transactions are explicit (BEGIN IMMEDIATE) and short
            conn = sqlite3.connect(p, timeout=timeout_s, isolation_level=None, check_same_thread=False)
        try:
            conn.execute(f"PRAGMA busy_timeout = {int(timeout_s * 1000)}")
            if not readonly:
                mode = conn.execute("PRAGMA journal_mode = WAL").fetchone()[0]
                if str(mode).lower() != "wal":
                    raise sqlite3.OperationalError(f"could not enable WAL on {p} (journal_mode={mode})")
                conn.execute(f"PRAGMA synchronous = {synchronous}")
                conn.execute("BEGIN IMMEDIATE")  # schema creation is atomic even with concurrent openers
                for stmt in filter(None, (s.strip() for s in _SCHEMA.split(";"))):
                    conn.execute(stmt)
                row = conn.execute("SELECT max(version) FROM schema_version").fetchone()
                if row[0] is None:
                    conn.execute("INSERT INTO schema_version (version) VALUES (?)", (SCHEMA_VERSION,))
                conn.execute("COMMIT")
            version = conn.execute("SELECT max(version) FROM schema_version").fetchone()[0]
            if version != SCHEMA_VERSION:
                raise MemoryBankError(f"{p}: memory bank schema version {version}, this letspi reads version "
                                      f"{SCHEMA_VERSION}; collect a new bank (`letspi collect --memory NEW.sqlite`)")
        except BaseException:
            conn.close()
            raise
        return cls(conn, p, readonly=readonly)

    # context manager --------------------------------------------------------------------------
    def __enter__(self) -> MemoryBank:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self._conn.close()

    # writing ---------------------------------------------------------------------------------
    def add(self, experience: Experience) -> bool:
        """Insert one experience (committed); an existing row of the same scenario and configuration is kept
        unless it is a fallback. Returns whether the bank changed."""
        cur = self._conn.execute(self._insert_sql(), _row_values(experience, _now()))
        self._own_writes += 1
        return cur.rowcount == 1

    def record_dataset(self, digest: str, path: str, n_scenarios: int) -> None:
        """Note a dataset the bank collected from (first sighting kept)."""
        self._conn.execute("INSERT OR IGNORE INTO datasets VALUES (?, ?, ?, ?)", (digest, path, n_scenarios, _now()))
        self._own_writes += 1

    def datasets(self) -> list[dict[str, Any]]:
        rows = self._conn.execute("SELECT digest, path, n_scenarios, first_seen FROM datasets ORDER BY first_seen")
        return [{"digest": r[0], "path": r[1], "n_scenarios": r[2], "first_seen": r[3]} for r in rows]

    def add_many(self, experiences: Iterable[Experience]) -> int:
        """Insert many in one transaction (all or nothing); returns how many were new."""
        sql = self._insert_sql()
        now = _now()
        self._conn.execute("BEGIN IMMEDIATE")
        try:
            new = 0
            for exp in experiences:
                new += self._conn.execute(sql, _row_values(exp, now)).rowcount
            self._conn.execute("COMMIT")
        except BaseException:
            self._conn.execute("ROLLBACK")
            raise
        self._own_writes += 1
        return new

    @staticmethod
    def _insert_sql() -> str:
        cols = ", ".join(_DATA_COLS)
        marks = ", ".join("?" for _ in _DATA_COLS)
        updates = ", ".join(f"{c} = excluded.{c}" for c in _DATA_COLS)
        return (f"INSERT INTO experiences ({cols}) VALUES ({marks}) ON CONFLICT (scenario_digest, config_key) "
                f"DO UPDATE SET {updates} WHERE experiences.fallback = 1")

    # reading ---------------------------------------------------------------------------------
    def has(self, scenario_digest: str, config_key: str) -> bool:
        """Whether a real (non-fallback) result for this scenario content and configuration exists."""
        sql = "SELECT 1 FROM experiences WHERE scenario_digest = ? AND config_key = ? AND fallback = 0"
        return self._conn.execute(sql, (scenario_digest, config_key)).fetchone() is not None

    def done_digests(self, config_key: str) -> set[str]:
        """Digests of every scenario with a real (non-fallback) result under ``config_key``."""
        rows = self._conn.execute(
            "SELECT scenario_digest FROM experiences WHERE config_key = ? AND fallback = 0", (config_key,))
        return {str(r[0]) for r in rows}

    def snapshot(self, config_key: str | None = None) -> tuple[np.ndarray, str]:
        """Row ids (ascending) of every retrievable memory (of ``config_key`` or all) and a SHA-256 over their
        (id, digest, configuration): the identity of what a fast planner built now can retrieve."""
        where, args = _where(True, config_key)
        rows = self._conn.execute(
            f"SELECT id, scenario_digest, config_key FROM experiences{where} ORDER BY id", args).fetchall()
        h = hashlib.sha256()
        for rid, digest, key in rows:
            h.update(f"{rid}:{digest}:{key}\n".encode())
        return np.array([r[0] for r in rows], dtype=np.int64), h.hexdigest()

    def count(self, validated_only: bool = True, config_key: str | None = None) -> int:
        where, args = _where(validated_only, config_key)
        return int(self._conn.execute(f"SELECT count(*) FROM experiences{where}", args).fetchone()[0])

    def _version(self) -> tuple[int, int]:
        """Changes when any connection commits (data_version: others; _own_writes: this one)."""
        return int(self._conn.execute("PRAGMA data_version").fetchone()[0]), self._own_writes

    def features_matrix(self, validated_only: bool = True, config_key: str | None = None) -> MemoryFeatures:
        """Row ids (M,) and features (M, 6) for matching; cached until the bank changes."""
        key = (validated_only, config_key)
        version = self._version()
        hit = self._cache.get(key)
        if hit is not None and hit[0] == version:
            return hit[1]
        where, args = _where(validated_only, config_key)
        rows = self._conn.execute(
            f"SELECT id, {', '.join(_FEATURE_COLS)}, ego_id, frame0, recording_key FROM experiences{where} ORDER BY id",
            args,
        ).fetchall()
        n_num = 1 + len(_FEATURE_COLS) + 2
        arr = np.array([r[:n_num] for r in rows], dtype=np.float64).reshape(-1, n_num)
        feats = MemoryFeatures(
            ids=arr[:, 0].astype(np.int64), features=np.ascontiguousarray(arr[:, 1:-2]),
            recording_key=np.array([r[-1] for r in rows], dtype=object), ego_id=arr[:, -2].astype(np.int64),
            frame0=arr[:, -1].astype(np.int64),
        )
        self._cache[key] = (version, feats)
        return feats

    def get(self, ids: Sequence[int] | np.ndarray) -> list[Experience]:
        """Experiences by row id, in the order of ``ids`` (KeyError for an unknown id)."""
        wanted = [int(i) for i in np.asarray(ids).reshape(-1)]
        if not wanted:
            return []
        found: dict[int, Experience] = {}
        for start in range(0, len(wanted), 500):  # stay below SQLite's bound-parameter limit
            chunk = sorted(set(wanted[start:start + 500]))
            marks = ", ".join("?" for _ in chunk)
            sql = f"SELECT {', '.join(_SELECT_COLS)} FROM experiences WHERE id IN ({marks})"
            for row in self._conn.execute(sql, chunk):
                found[int(row[0])] = _from_row(row)
        missing = [i for i in wanted if i not in found]
        if missing:
            raise KeyError(f"no experiences with ids {missing[:10]}")
        return [found[i] for i in wanted]

    def iter_experiences(self, validated_only: bool = False, config_key: str | None = None,
                         batch_size: int = 256) -> Iterator[Experience]:
        """All experiences in id order, ``batch_size`` rows at a time (keyset pagination: a concurrent writer
        never makes it skip or repeat rows)."""
        where, args = _where(validated_only, config_key)
        last = 0
        cond = f"{where} AND id > ?" if where else " WHERE id > ?"
        sql = f"SELECT {', '.join(_SELECT_COLS)} FROM experiences{cond} ORDER BY id LIMIT ?"
        while True:
            rows = self._conn.execute(sql, (*args, last, batch_size)).fetchall()
            if not rows:
                return
            for row in rows:
                yield _from_row(row)
            last = int(rows[-1][0])

    def sample_fraction(self, fraction: float, seed: int = 0, validated_only: bool = True,
                        config_key: str | None = None) -> MemorySubset:
        """The first round(fraction x count) rows ordered by a hash of (seed, digest, configuration): subsets of
        one seed are nested (10 % inside 50 %) and independent of insertion order."""
        if not 0.0 <= fraction <= 1.0:
            raise ValueError(f"fraction must be in [0, 1], got {fraction}")
        where, args = _where(validated_only, config_key)
        rows = self._conn.execute(f"SELECT id, scenario_digest, config_key FROM experiences{where}", args).fetchall()
        ranked = sorted(rows, key=lambda r: (_sample_rank(seed, r[1], r[2]), r[0]))
        n = round(fraction * len(rows))
        ids = np.array(sorted(r[0] for r in ranked[:n]), dtype=np.int64)
        return MemorySubset(self, ids, fraction=fraction, seed=seed)

    def journal_mode(self) -> str:
        return str(self._conn.execute("PRAGMA journal_mode").fetchone()[0]).lower()

    def integrity_check(self) -> str:
        """SQLite's ``PRAGMA integrity_check`` ("ok" when consistent)."""
        return str(self._conn.execute("PRAGMA integrity_check").fetchone()[0])


@dataclass(frozen=True)
class MemorySubset:
    """A fixed set of row ids of a bank (the memory-size ablation): same reading API, no copy."""

    bank: MemoryBank
    ids: np.ndarray
    fraction: float
    seed: int

    def count(self) -> int:
        return int(self.ids.shape[0])

    def __len__(self) -> int:
        return self.count()

    def features_matrix(self) -> MemoryFeatures:
        """The retrieval view of the subset, ascending id."""
        full = self.bank.features_matrix(validated_only=False)
        return full.take(np.searchsorted(full.ids, self.ids))

    def get(self, ids: Sequence[int] | np.ndarray) -> list[Experience]:
        return self.bank.get(ids)

    def iter_experiences(self) -> Iterator[Experience]:
        for start in range(0, len(self.ids), 256):
            yield from self.bank.get(self.ids[start:start + 256])
