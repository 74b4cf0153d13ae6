"""Response cache: keys, round trip, concurrent writers in two processes."""

from __future__ import annotations

import multiprocessing as mp
from pathlib import Path

from letspi.llm.cache import CachedEntry, ResponseCache, cache_key
from letspi.llm.types import DecodingSettings, message

MSGS = [message("system", "s"), message("user", "u")]


def test_key_depends_on_everything() -> None:
    base = cache_key("llamacpp:x", MSGS, DecodingSettings(), {"type": "object"})
    assert base == cache_key("llamacpp:x", list(MSGS), DecodingSettings(), {"type": "object"})
    assert base != cache_key("llamacpp:y", MSGS, DecodingSettings(), {"type": "object"})
    assert base != cache_key("llamacpp:x", [*MSGS, message("user", "more")], DecodingSettings(), {"type": "object"})
    assert base != cache_key("llamacpp:x", MSGS, DecodingSettings(seed=1), {"type": "object"})
    assert base != cache_key("llamacpp:x", MSGS, DecodingSettings(), None)


def test_round_trip_and_persistence(tmp_path: Path) -> None:
    path = tmp_path / "sub" / "c.sqlite"
    c = ResponseCache(path)
    assert c.get("k") is None
    c.put("k", "spec", CachedEntry("héllo {}", 10, 5, 1.25))
    c.put("k", "spec", CachedEntry("héllo {}", 10, 5, 1.25))  # duplicate write is harmless
    c.close()
    again = ResponseCache(path)
    assert again.get("k") == CachedEntry("héllo {}", 10, 5, 1.25) and len(again) == 1
    again.clear()
    assert len(again) == 0


def _writer(path: str, tag: str, n: int) -> None:
    cache = ResponseCache(path)
    for i in range(n):
        cache.put(f"{tag}-{i}", "spec", CachedEntry(f"text {tag} {i}", i, i, 0.1))
        cache.get(f"{tag}-{i // 2}")


def test_concurrent_writers_two_processes(tmp_path: Path) -> None:
    path = str(tmp_path / "shared.sqlite")
    ResponseCache(path)  # create the table up front (WAL is set per connection anyway)
    ctx = mp.get_context("spawn")
    procs = [ctx.Process(target=_writer, args=(path, tag, 150)) for tag in ("a", "b")]
    for p in procs:
        p.start()
    for p in procs:
        p.join(timeout=120)
        assert p.exitcode == 0
    cache = ResponseCache(path)
    assert len(cache) == 300
    assert cache.get("a-149") == CachedEntry("text a 149", 149, 149, 0.1)
    assert cache.get("b-0") is not None


def test_unusable_cache_is_one_clear_error(tmp_path: Path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    import pytest

    from letspi.llm.client import ParamAdvisor
    from letspi.llm.types import LLMConfigError, ResponseCacheError

    garbage = tmp_path / "llm_cache.sqlite"
    garbage.write_bytes(b"this is not an SQLite database" * 100)
    with pytest.raises(ResponseCacheError) as info:
        ResponseCache(garbage)
    assert str(info.value).startswith(f"{garbage}: the LLM response cache cannot be used")
    assert "delete the file" in str(info.value) and isinstance(info.value, LLMConfigError)
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    monkeypatch.setenv("LETSPI_CACHE_DIR", str(blocker / "sub"))  # a directory inside a file
    with pytest.raises(ResponseCacheError, match="LETSPI_CACHE_DIR"):
        ParamAdvisor("scripted:default")


def test_cache_damaged_while_open_is_a_clear_error(tmp_path: Path) -> None:
    import pytest

    from letspi.llm.types import ResponseCacheError

    cache = ResponseCache(tmp_path / "c.sqlite")
    cache.put("k", "spec", CachedEntry("t", 1, 2, 0.1))
    cache.close()
    (tmp_path / "c.sqlite").write_bytes(b"\x00" * 4096)
    for name in ("c.sqlite-wal", "c.sqlite-shm"):
        (tmp_path / name).unlink(missing_ok=True)
    with pytest.raises(ResponseCacheError):
        cache.get("k")
