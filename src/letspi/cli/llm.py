"""``letspi llm``: check LLM backends, list backend kinds and embedded models, benchmark them, show the prompt
fingerprint."""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path
from typing import Annotated, Any

import typer

from letspi.assembly.resolve import prompt_sha256
from letspi.fsutil import atomic_write_text
from letspi.llm.backends.llamacpp import LlamaCppBackend
from letspi.llm.client import ParamAdvisor, RetryPolicy
from letspi.llm.fingerprint import prompt_samples
from letspi.llm.latency import bench_models, bench_scenarios, standard_messages
from letspi.llm.models import EMBEDDED_MODELS, is_fine_tuned
from letspi.llm.prompts import render_fast_prompt, render_physics_prompt, system_prompt
from letspi.llm.spec import ENTRY_POINT_GROUP, backend_origin, backend_table, installed_backends
from letspi.llm.types import DecodingSettings, LLMConfigError, LLMError, message
from letspi.method.phases import messages_text
from letspi.method.prompt_samples import prompt_text_samples

app = typer.Typer(help="LLM backends: check a spec, list backend kinds and embedded models, benchmark; the prompt "
                       "fingerprint.",
                  no_args_is_help=True, rich_markup_mode=None)

_TINY_USER = (
    "Free road: ego car at 30.0 m/s in the middle lane of 3, no neighbours, goal 150.0 m ahead in its lane. Answer:"
)


@app.command("check")
def check(
    spec: Annotated[str, typer.Argument(help="Backend spec, e.g. llamacpp:smollm2-135m, ollama:llama3.1:8b "
                                                "(letspi llm backends lists the kinds).")],
    prompt: Annotated[
        str, typer.Option(help="auto | tiny | fast | physics | compact (fast, physics and compact on a close-leader "
                               "scenario; auto: compact for the fine-tuned model, else tiny).")
    ] = "auto",
    no_cache: Annotated[bool, typer.Option("--no-cache", help="Do not read or write the response cache.")] = False,
    timeout: Annotated[float, typer.Option(help="Per-call timeout in seconds.")] = RetryPolicy.timeout_s,
    attempts: Annotated[int, typer.Option(help="Maximum calls (1 = no retry).")] = RetryPolicy.max_attempts,
    max_tokens: Annotated[int, typer.Option(help="Reply token limit.")] = DecodingSettings.max_tokens,
) -> None:
    """Send one prompt to SPEC and print the reply. Prints latency, tokens and the parsed reply as JSON; for
    embedded models also the load-time self-check (batched vs token-by-token prompt evaluation) and the
    llama.cpp runtime. Exit code 0: the model gave a valid reply; 1: it fell back to defaults; 2:
    configuration error (including a failed strict self-check).
    """
    if prompt not in ("auto", "tiny", "fast", "physics", "compact"):
        raise typer.BadParameter("prompt must be auto, tiny, fast, physics or compact")
    if prompt == "auto":
        name = spec.partition(":")[2]
        prompt = "compact" if spec.startswith("llamacpp:") and is_fine_tuned(name) else "tiny"
    try:
        adv = ParamAdvisor(
            spec,
            cache=None if no_cache else "default",
            retry=RetryPolicy(max_attempts=attempts, timeout_s=timeout),
            settings=DecodingSettings(max_tokens=max_tokens),
        )
        if prompt == "tiny":
            msgs = [message("system", system_prompt("fast")), message("user", _TINY_USER)]
            variant = "fast"
        elif prompt == "compact":
            msgs, variant = standard_messages(), "fast"
        else:
            desc = bench_scenarios()["close_leader"]
            msgs = render_fast_prompt(desc) if prompt == "fast" else render_physics_prompt(desc)
            variant = prompt
        advice = adv.advise(msgs, variant="fast" if variant == "fast" else "physics")
    except LLMConfigError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(code=2) from exc
    except LLMError as exc:  # e.g. server unreachable on every attempt
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(code=2) from exc
    out = advice.summary()
    out["prompt"] = prompt
    if isinstance(adv.backend, LlamaCppBackend):
        loaded = adv.backend.loaded()
        out["self_check"] = {"summary": loaded.check.summary(), **asdict(loaded.check)}
        out["runtime"] = adv.backend.runtime.identity()
        out["threads_used"] = loaded.threads_used
    out["reply_text"] = advice.attempts[-1].text if advice.attempts else None
    out["attempt_errors"] = [a.error for a in advice.attempts if not a.ok]
    typer.echo(json.dumps(out, indent=2, ensure_ascii=False))
    if advice.fallback:
        raise typer.Exit(code=1)


@app.command("backends")
def backends(
    as_json: Annotated[bool, typer.Option("--json", help="Print a JSON list instead of a table.")] = False,
) -> None:
    """List the backend kinds a spec may name (PREFIX:MODEL): built in and from installed packages."""
    rows: list[dict[str, Any]] = [
        {"prefix": k.prefix, "doc": k.doc, "forms": list(k.forms), "default_concurrency": k.default_concurrency,
         "local_weights": k.local_weights is not None, "source": backend_origin(k.prefix)} for k in backend_table()]
    if as_json:
        typer.echo(json.dumps(rows, indent=2))
    else:
        width = max(len(row["prefix"]) for row in rows)
        for row in rows:
            source = "" if row["source"] == "built in" else f" [{row['source']}]"
            typer.echo(f"{row['prefix']:<{width}}  {row['doc']}{source}")
            typer.echo(f"{'':<{width}}  forms: {', '.join(row['forms'])}; concurrency {row['default_concurrency']}")
        typer.echo(f"\nInstalled packages add kinds through the entry-point group {ENTRY_POINT_GROUP!r}.")
    for problem in installed_backends().problems.values():
        typer.echo(f"left out: {problem}", err=True)


@app.command("models")
def models(
    locate: Annotated[bool, typer.Option(help="Also resolve each model's file (assembles Gemma once).")] = False,
) -> None:
    """List the embedded models and their PyPI packages. Use one as --llm llamacpp:NAME."""
    rows = []
    for m in EMBEDDED_MODELS.values():
        row: dict[str, str] = {"spec": f"llamacpp:{m.name}", "package": m.pip_package, "description": m.description}
        if locate:
            try:
                row["path"] = str(m.locate())
            except LLMConfigError as exc:
                row["error"] = str(exc)
        rows.append(row)
    typer.echo(json.dumps(rows, indent=2))


@app.command("fingerprint")
def fingerprint(
    out: Annotated[Path | None, typer.Option(help="Also write every sample prompt the fingerprint hashes as a text "
                                                  "file into this directory (diff two such directories to see "
                                                  "what a prompt change changes).")] = None,
) -> None:
    """Print the prompt fingerprint. The SHA-256 of the prompts as every prompt style renders them for fixed
    synthetic scenes; it is part of every LLM configuration key, so when it changes, stored LLM results and
    memory collections no longer match the configuration."""
    if out is not None:
        texts = {name: s if isinstance(s, str) else messages_text(s) for name, s in prompt_samples().items()}
        texts.update(prompt_text_samples())
        for name, text in texts.items():
            path = out / f"{name}.txt"
            path.parent.mkdir(parents=True, exist_ok=True)
            atomic_write_text(path, text + "\n")
        typer.echo(f"wrote {len(texts)} sample prompts to {out}", err=True)
    typer.echo(prompt_sha256())


@app.command("bench")
def bench(
    model: Annotated[
        list[str] | None, typer.Option("--model", help="Embedded model name (repeatable); default both.")
    ] = None,
    repeats: Annotated[int, typer.Option(help="Repetitions of each latency measurement (median).")] = 2,
    behaviour: Annotated[bool, typer.Option(help="Also run the five-scenario behaviour check.")] = True,
) -> None:
    """Benchmark the embedded models. Latency, tokens, prefix- and cache-hit speedups and behaviour (JSON)."""
    try:
        result = bench_models(
            tuple(model) if model else ("smollm2-135m", "gemma3-270m"), repeats=repeats, behaviour=behaviour
        )
    except LLMConfigError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(code=2) from exc
    typer.echo(json.dumps(result, indent=2))
