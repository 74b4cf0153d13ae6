"""The LLM side of LetsPi (paper §III-B, §III-C, §III-E): prompts, backends, reply validation, retries, cache.

An LLM reads a scenario description and returns six social-force parameters, two goal adjustment factors
and a rationale as JSON (``ParamAdvisor.advise``). Importing this package loads no model and no optional
dependency (llama-cpp-python is imported on first use of a ``llamacpp:`` backend).
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
