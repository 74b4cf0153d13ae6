"""Shared httpx helpers for the HTTP backends."""

from __future__ import annotations

import math
import re
import time
from datetime import UTC
from email.utils import parsedate_to_datetime
from typing import Any

import httpx

from letspi.llm.types import BackendUnavailableError, LLMTimeoutError, LLMTransportError, ServerBusyError

_SECONDS_RE = re.compile(r"\s*\d+(?:\.\d+)?\s*")
#: Connections kept alive per client: up to ``--concurrency`` requests in flight, none opening a new connection.
KEEPALIVE_CONNECTIONS = 256


def pooled_client() -> httpx.Client:
    """An ``httpx.Client`` for many concurrent requests: no connection cap (the runner bounds requests in
    flight; waiting for a pooled connection would count against the timeout)."""
    return httpx.Client(limits=httpx.Limits(max_connections=None, max_keepalive_connections=KEEPALIVE_CONNECTIONS))


def post_json(
    client: httpx.Client,
    url: str,
    payload: dict[str, Any],
    *,
    timeout_s: float,
    headers: dict[str, str] | None = None,
    unreachable_hint: str,
) -> httpx.Response:
    """POST JSON; map httpx failures onto the letspi error taxonomy (status codes are the caller's)."""
    # Connecting gets a short budget of its own: a dead server should fail fast, a slow model not.
    timeout = httpx.Timeout(timeout_s, connect=min(timeout_s, 5.0))
    try:
        return client.post(url, json=payload, timeout=timeout, headers=headers)
    except httpx.ConnectError as exc:
        raise BackendUnavailableError(f"cannot reach {url}: {exc}. {unreachable_hint}") from exc
    except httpx.TimeoutException as exc:
        raise LLMTimeoutError(f"{url}: no reply within {timeout_s:.1f} s ({type(exc).__name__})") from exc
    except httpx.HTTPError as exc:
        raise LLMTransportError(f"{url}: {type(exc).__name__}: {exc}") from exc


def error_text(resp: httpx.Response) -> str:
    """The server's error message: JSON ``error`` (string or ``{"message": ...}``) or the raw body."""
    try:
        body = resp.json()
    except ValueError:
        return resp.text[:500]
    if isinstance(body, dict):
        err = body.get("error", body.get("detail", body))
        if isinstance(err, dict):
            err = err.get("message", err)
        return str(err)[:500]
    return str(body)[:500]


def parse_retry_after(value: str | None, *, now: float | None = None) -> float | None:
    """Seconds to wait from a ``Retry-After`` header (delay-seconds or an HTTP date; past date: 0), or None."""
    if value is None:
        return None
    if _SECONDS_RE.fullmatch(value):
        seconds = float(value)
        return seconds if math.isfinite(seconds) else math.inf
    try:
        when = parsedate_to_datetime(value.strip())
    except (TypeError, ValueError, IndexError, OverflowError):
        return None
    if when.tzinfo is None:  # RFC 9110 dates are GMT
        when = when.replace(tzinfo=UTC)
    try:
        target = when.timestamp()
    except (OverflowError, OSError, ValueError):
        return None
    return max(target - (time.time() if now is None else now), 0.0)


def raise_for_server_error(resp: httpx.Response, url: str) -> None:
    """Raise the retryable error for HTTP 429 and 5xx (``ServerBusyError`` for 429/503), carrying
    the server's ``Retry-After``; other statuses are the caller's."""
    code = resp.status_code
    if code != 429 and code < 500:
        return
    retry_after = parse_retry_after(resp.headers.get("Retry-After"))
    hint = f" (Retry-After: {retry_after:g} s)" if retry_after is not None else ""
    cls = ServerBusyError if code in (429, 503) else LLMTransportError
    what = "rate limited" if code == 429 else "server busy" if code == 503 else "server error"
    raise cls(f"{url}: HTTP {code} ({what}): {error_text(resp)}{hint}", status=code, retry_after_s=retry_after)
