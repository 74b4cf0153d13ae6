"""letspi.llm: the LLM side of LetsPi (paper §III-B, §III-C, §III-E).

An LLM reads a scenario description and returns six social-force parameters, two goal
adjustment factors and a rationale as JSON. This package renders the prompts, talks to the
model through one small backend interface, validates and clamps the reply, retries, falls back,
and caches replies on disk.

Typical use::

    from letspi.llm import ParamAdvisor, describe_scenario, render_physics_prompt

    advisor = ParamAdvisor("llamacpp:gemma3-270m")          # or ollama:..., openai:...@url
    desc = describe_scenario(scenario, goal_xy=(150.0, 0.0))
    advice = advisor.advise(render_physics_prompt(desc), variant="physics")
    advice.reply.params(), advice.reply.goal_factors(), advice.fallback, advice.clamped

Importing this package loads no model and no optional dependency (llama-cpp-python is imported
on first use of a ``llamacpp:`` backend).
"""

from letspi.llm.cache import ResponseCache, default_cache_dir
from letspi.llm.client import Advice, Attempt, ParamAdvisor, RetryPolicy
from letspi.llm.describe import ScenarioDescription, describe_scenario, targeted_guidance
from letspi.llm.parse import ParsedReply, parse_reply
from letspi.llm.prompts import MemoryExample, render_fast_prompt, render_physics_prompt, system_prompt
from letspi.llm.schema import (
    DEFAULT_REPLY,
    FIELD_RANGES,
    GOAL_FACTOR_RANGES,
    LLM_PARAM_RANGES,
    PlannerReply,
    Variant,
    reply_json_schema,
)
from letspi.llm.spec import BackendSpec, make_backend, parse_spec
from letspi.llm.types import (
    BackendUnavailableError,
    DecodingSettings,
    LLMBackend,
    LLMConfigError,
    LLMError,
    LLMResponse,
    LLMTimeoutError,
    LLMTransportError,
    Message,
    MissingDependencyError,
    ModelNotFoundError,
    ReplyParseError,
    ResponseCacheError,
    ServerBusyError,
    UnknownBackendError,
    message,
)

__all__ = [
    "DEFAULT_REPLY",
    "FIELD_RANGES",
    "GOAL_FACTOR_RANGES",
    "LLM_PARAM_RANGES",
    "Advice",
    "Attempt",
    "BackendSpec",
    "BackendUnavailableError",
    "DecodingSettings",
    "LLMBackend",
    "LLMConfigError",
    "LLMError",
    "LLMResponse",
    "LLMTimeoutError",
    "LLMTransportError",
    "MemoryExample",
    "Message",
    "MissingDependencyError",
    "ModelNotFoundError",
    "ParamAdvisor",
    "ParsedReply",
    "PlannerReply",
    "ReplyParseError",
    "ResponseCache",
    "ResponseCacheError",
    "RetryPolicy",
    "ScenarioDescription",
    "ServerBusyError",
    "UnknownBackendError",
    "Variant",
    "default_cache_dir",
    "describe_scenario",
    "make_backend",
    "message",
    "parse_reply",
    "parse_spec",
    "render_fast_prompt",
    "render_physics_prompt",
    "reply_json_schema",
    "system_prompt",
    "targeted_guidance",
]
