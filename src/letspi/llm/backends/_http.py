"""Shared httpx helpers for the HTTP backends."""

from __future__ import annotations

from typing import Any

import httpx

from letspi.llm.types import BackendUnavailableError, LLMTimeoutError, LLMTransportError


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
