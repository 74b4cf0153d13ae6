"""Result keys do not move: the content key of every built-in planner kind, option variants and the
closed-loop evaluation identity, computed on main (c7da148) before issue 26 refactored options,
closed-loop settings and the planner table.

Results directories and memory banks are keyed by these values, so moving code must not move them.
Unlike ``test_planner_table.py`` this test uses the shipped data as it is (goal, gnp and frenet
weights, sf parameters, the embedded model's files) and patches nothing: only the prompt fingerprint
(which issue 26 item 4 changes on purpose), the fingerprint of weights written here (``np.savez``
stamps the time into the file), the decision step's shipped data (issue 28 refits its presets and
risk model: their values, and the threshold recommended with the model) and the embedded model's weights
(the shipped adapter is retrained, and the base runs from an F16 copy: their SHA-256) are replaced by
constants in the identity before it is hashed. Behaviour that changes on purpose moves keys here:
issue 28's verification of the fast phase's choice (``verify``) moved letspi-fast's and letspi-fs's; issue
36's shield that leaves the decision step's presets alone (``shield_presets``) moved sf-check's and the deciding
letspi-fast's (``--shield-presets`` gives their keys of before); issue 36's verification off by default moved them
again (``--verify`` gives the keys of before).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from letspi.assembly.planners import build_planners, resolve_planner
from letspi.assembly.resolve import Resolver
from letspi.evaluation.closed_loop import mode_settings, planner_evaluation
from letspi.evaluation.results import planner_record, run_record
from letspi.keyed import key_of
from letspi.learned.weights import save_weights
from letspi.method.memory import MemoryBank
from letspi.metrics.config import MetricsConfig
from letspi.physics.params import SocialForceParams
from letspi.planners.frenet import FrenetWeights, save_frenet_weights
from letspi.planners.options import PlannerOptions
from letspi.planners.sf_params import save_sf_params
from letspi.scenario.build import VehicleSpec, straight_road_scenario
from letspi.scenario.identity import scenario_digests
from letspi.simulation.config import ClosedLoopConfig, HandoverConfig
from letspi.simulation.schedule import DualRateConfig

SCRIPTED = "scripted:default"
LOG, REACTIVE, HYBRID = "closed-loop-log", "closed-loop-reactive", "closed-loop-hybrid"


#: identity fields whose values are shipped data that other issues change on purpose (module docstring)
DATA_FIELDS = {"prompt_sha256": "prompt", "preset_names": "presets", "preset_values": "presets",
               "risk_model_sha256": "risk-model", "model_sha256": "embedded-model", "adapter_sha256": "adapter"}
GIVEN_THRESHOLD = 0.5  # a --gate-threshold of a variant below (kept); any other is the risk model's


def _normalised(value: Any, parent: str = "") -> Any:
    """The identity with the fields of shipped data replaced (module docstring)."""
    if isinstance(value, dict):
        out = {}
        for k, v in value.items():
            if k in DATA_FIELDS and v is not None:
                out[k] = DATA_FIELDS[k]
            elif k == "weights_sha256" and parent == "mlp":
                out[k] = "mlp-weights"
            elif k == "gate_threshold" and v is not None and v != GIVEN_THRESHOLD:
                out[k] = "recommended"
            else:
                out[k] = _normalised(v, k)
        return out
    if isinstance(value, list):
        return [_normalised(v, parent) for v in value]
    return value


def pinned_key(identity: dict[str, Any]) -> str:
    return key_of(_normalised(identity))


@pytest.fixture
def files(tmp_path: Path) -> dict[str, Path]:
    """An empty memory bank, an mlp weights directory, a parameter file and a frenet weights file of
    the code defaults (their paths are cosmetic: not part of any key)."""
    memory = tmp_path / "memory.sqlite"
    MemoryBank.open(memory).close()
    return {"memory": memory, "mlp": save_weights(tmp_path / "mlp", {"w": np.zeros(3)}, {"model": "param-mlp"}),
            "sf": save_sf_params(tmp_path / "sf.json", SocialForceParams(), {}, {}),
            "frenet": save_frenet_weights(tmp_path / "frenet.json", FrenetWeights(), {}, {})}


#: every kind with the default options (the LLM kinds on the scripted backend; the embedded model below)
DEFAULT_KEYS = {
    "human": "70ac28e00fca6bcb", "cv": "7e67bce47ff4cc19", "idm": "6be513ccf5f29f87", "sf": "a21f63b8023b7466",
    "sf-opt": "f63396bbbbc3c5ec", "gnp": "df7b5695c2549f70", "frenet": "51ebfe8893f68f60",
    "mlp": "30fb7572d9e66bf6", "llm": "0035c0d451122504", "letspi-memory": "e09321132070e1d0",
    "letspi-fast": "e6fe29ec90f36ac0", "letspi-fs": "a66c3746e9059b93",
    "sf-check": "3cad719e7654662f",  # issue 28's kind, pinned on main at 9cb44e3, presets and risk model replaced
}
#: one option changed at a time (``@name``: a file of the fixture): the kinds whose key it moves (the other
#: kinds keep their default key); ``refused`` where resolution refuses the option
VARIANTS: dict[str, tuple[dict[str, Any], dict[str, str]]] = {
    "neighbours": ({"neighbour_mode": "constant_velocity"}, {"idm": "7ebf8bb605573595", "sf": "9d8c0b64e7c852b6",
        "sf-check": "de76ab9e8ebc95bb", "sf-opt": "a93543ee377f5fdd", "gnp": "80541cd6172574bb",
        "frenet": "2cb73f85d2d8c293", "mlp": "3800ea4877565340", "llm": "3e9c860384ea6192",
        "letspi-memory": "239485c4d350f9f0", "letspi-fast": "2070d80d08eaacf6", "letspi-fs": "f6fef997bd3eac4e"}),
    "kinematic goals": ({"goals": "kinematic"}, {"sf": "5c341163810f3bb0", "sf-opt": "8bad0e27c282074e",
        "gnp": "refused", "sf-check": "d386cc68748eb459", "frenet": "842a6dbf3138d608", "mlp": "a31e4e9832425486",
        "llm": "69c98101af310ebe", "letspi-memory": "913690e54903e33a", "letspi-fast": "c764a90d7a0e8aa1",
        "letspi-fs": "9bb09b47748ebbb7"}),
    "oracle goals": ({"goals": "oracle"}, {"sf": "4ac840df89cec3af", "sf-opt": "37d980c247977be5", "gnp": "refused",
        "sf-check": "9b77b2c941edc1bb", "frenet": "439d00fefb00f383", "mlp": "e9c670d41bb5436d",
        "llm": "af510e4d3f3e5248", "letspi-memory": "167e5b418e9be2f8", "letspi-fast": "301b79c85fd6e0e0",
        "letspi-fs": "95edead385379532"}),
    "sf parameter file": ({"sf_params_file": "@sf"}, {"sf": "49ea889f0a86441c", "sf-opt": "59140a2db3b5cd12",
        "sf-check": "02f2e5b2e42da962", "mlp": "9ef1ad2c6504591c", "llm": "48cec17611cf1242",
        "letspi-memory": "fbcdf12c32ca6083", "letspi-fast": "5dacdb41a6d20cbf", "letspi-fs": "025a394a9b1fa0a7"}),
    "frenet weights file": ({"frenet_weights_file": "@frenet"}, {"frenet": "60ea6946bb5bdc07"}),
    "top-k": ({"top_k": 5}, {"letspi-fast": "06a24917eef61dad", "letspi-fs": "a372138f1d530609"}),
    "reflection": ({"max_iterations": 1}, {"letspi-memory": "a369e141e0df3e35"}),
    "no goal adjustment": ({"goal_adjustment": False}, {"llm": "3615febcf2621d4f",
        "letspi-memory": "eae8b3eeda48fb83"}),
    "same vehicle": ({"allow_same_vehicle": True}, {"letspi-fast": "487e37655559fb70",
        "letspi-fs": "7a389901936ca40b"}),
    "memory fraction": ({"memory_fraction": 0.5}, {"letspi-fast": "624f8f6483305ab8",
        "letspi-fs": "7dbb97d4fc59e126"}),
    "memory seed": ({"memory_seed": 3}, {"letspi-fast": "eaa1c5f805a168a4", "letspi-fs": "c19af402ef4a21c9"}),
    "memory key": ({"memory_key": "0123456789abcdef"}, {"letspi-fast": "296d20bd09ada67b",
        "letspi-fs": "04f8071ccfd1fe7c"}),
    "no shield": ({"shield": False}, {"llm": "b2f1bf72dde95a66", "letspi-memory": "72e49b6cdb022509",
        "letspi-fast": "77793932b6d563cf", "letspi-fs": "a4e42b056b4494b7", "sf-check": "c3630e9eac3c951b"}),
    # the decision step (issue 28; pinned on main at 9cb44e3, presets and risk model replaced)
    "no gate": ({"gate": False}, {"sf-check": "d2a7c8a2684495ad"}),
    "gate threshold": ({"gate_threshold": 0.5}, {"sf-check": "212382e42cb57d63"}),
    "no adverse": ({"adverse": False}, {"sf-check": "c418f62775922276"}),
    "decide": ({"decide": True}, {"llm": "94aa85039b987d52", "letspi-memory": "db8a47332a863b08",
        "letspi-fast": "358ca1b24309a5a1", "letspi-fs": "eb2b62e796104e6f"}),
    "compact prompt": ({"prompt_style": "compact"}, {"llm": "465c6c7af86c0d4e", "letspi-memory": "94f7ab4838a8f269",
        "letspi-fast": "4fe8ce85cf6eaea5", "letspi-fs": "67f02206d47f224b"}),
    "cosmetic only": ({"llm_cache": False, "llm_timeout_s": 12.0}, {}),
}
#: the LLM kinds on the embedded default model (its weights, adapter and llama.cpp runtime fingerprinted);
#: moved on purpose by issue 28's shipped adapter (prompt style choice) and the fast phase's verification;
#: recomputed with the weights' digests replaced (``DATA_FIELDS``)
EMBEDDED_KEYS = {"llm": "72995e49342617ce", "letspi-memory": "28b4e739ba99a9a9", "letspi-fast": "c2fae81372712064",
                 "letspi-fs": "6fb882405039e018"}
COLLECTION_KEYS = {"scripted": "216bc7d8c4de867c", "embedded": "9a40f3e2d34c4be2"}


def _options(files: dict[str, Path], **values: Any) -> PlannerOptions:
    chosen: dict[str, Any] = {"llm": SCRIPTED, "fast_llm": SCRIPTED, "memory": files["memory"],
                              "mlp_weights": files["mlp"]}
    for name, value in values.items():
        chosen[name] = files[value[1:]] if isinstance(value, str) and value.startswith("@") else value
    return PlannerOptions(**chosen)


def _key(options: PlannerOptions, kind: str) -> str:
    try:
        return pinned_key(resolve_planner(kind, options, env={}).identity())
    except ValueError:
        return "refused"


def test_every_kind_keeps_its_default_key(files: dict[str, Path]) -> None:
    options = _options(files)
    assert {kind: _key(options, kind) for kind in DEFAULT_KEYS} == DEFAULT_KEYS


@pytest.mark.parametrize("variant", list(VARIANTS))
def test_each_option_moves_exactly_the_keys_it_moved_before(files: dict[str, Path], variant: str) -> None:
    values, moved = VARIANTS[variant]
    options = _options(files, **values)
    assert {kind: _key(options, kind) for kind in DEFAULT_KEYS} == {**DEFAULT_KEYS, **moved}


def test_the_embedded_model_and_the_collection_keep_their_keys(files: dict[str, Path]) -> None:
    embedded = PlannerOptions(memory=files["memory"])
    assert {kind: _key(embedded, kind) for kind in EMBEDDED_KEYS} == EMBEDDED_KEYS
    # --verify: the keys the fast phase had while verification was on by default
    verified = PlannerOptions(memory=files["memory"], verify=True)
    assert {kind: _key(verified, kind) for kind in ("letspi-fast", "letspi-fs")} == {
        "letspi-fast": "a76f30d4471a335e", "letspi-fs": "e98ee5aed5036e1e"}
    # --no-verify --shield-presets: the model's choice stands and the shield checks every plan, under the key
    # the fast phase had before verification
    unverified = PlannerOptions(memory=files["memory"], verify=False, shield_presets=True)
    assert {kind: _key(unverified, kind) for kind in ("letspi-fast", "letspi-fs")} == {
        "letspi-fast": "f99ff4f76cde4b0d", "letspi-fs": "6fb882405039e018"}  # = main before verification
    assert {"scripted": pinned_key(Resolver(_options(files), env={}).memory_phase().identity()),
            "embedded": pinned_key(Resolver(embedded, env={}).memory_phase().identity())} == COLLECTION_KEYS


def test_the_closed_loop_identity_keeps_its_keys(files: dict[str, Path]) -> None:
    """``run.json``'s mode settings, and each planner's key with its evaluation (mode, own replanning
    period; the LLM planners' dual-rate schedule), as on main."""
    mask = np.zeros((3, 8), dtype=bool)
    mask[1, 2] = True
    # SUMO keeps its keys; the log replay (closed-loop-log's default) has its own
    assert {mode: key_of(mode_settings(ClosedLoopConfig(mode, simulator="sumo"), mask))  # type: ignore[arg-type]
            for mode in (LOG, REACTIVE, HYBRID)} == {
        LOG: "4636b34f162b3205", REACTIVE: "00f3fa4168aaeab7", HYBRID: "1517b8b485841990"}
    assert key_of(mode_settings(ClosedLoopConfig(LOG), mask)) == "2c97be9e38cd84ba"  # type: ignore[arg-type]
    wider = ClosedLoopConfig(HYBRID, handover=HandoverConfig(lanes=1))  # type: ignore[arg-type]
    assert key_of(mode_settings(wider, mask)) == "d8ef66751ea4949b"
    assert key_of(mode_settings(ClosedLoopConfig(HYBRID), None)) == "0d072afca6382dec"  # type: ignore[arg-type]
    # workers, chunk size and the GUI change no answer, so no key
    busy = ClosedLoopConfig(HYBRID, workers=3, chunk_size=5, sumo_gui=True)  # type: ignore[arg-type]
    assert key_of(mode_settings(busy, mask)) == "1517b8b485841990"

    built = build_planners(["sf", "letspi-fast", "slow=sf"], _options(files, llm_cache=False))
    keys = {}
    # release "off" keeps the keys of the results made before held presets could be released
    for dual in (DualRateConfig(2.5, 0.4, release="off"), DualRateConfig(release="off")):
        settings = ClosedLoopConfig(HYBRID, replan_s=0.5, planner_replan_s={"letspi-fast": 0.2, "slow": 2.0},  # type: ignore[arg-type]
                                    dual_rate=dual)
        for b in built:
            evaluation = planner_evaluation(settings, b)
            keys[f"{b.name} {dual.llm_latency_s}"] = pinned_key(planner_record(b, evaluation)["identity"])
    for b in built:
        keys[f"{b.name} open"] = pinned_key(planner_record(b)["identity"])
    assert keys == {
        "sf 0.4": "26c338c8fd692ffe", "letspi-fast 0.4": "8035a17c65731a16", "slow 0.4": "638c09678f690f04",
        "sf None": "26c338c8fd692ffe", "letspi-fast None": "f7cec8bf78597b72", "slow None": "638c09678f690f04",
        "sf open": DEFAULT_KEYS["sf"], "letspi-fast open": DEFAULT_KEYS["letspi-fast"], "slow open": DEFAULT_KEYS["sf"],
    }
    released = {b.name: pinned_key(planner_record(b, planner_evaluation(
        ClosedLoopConfig(HYBRID, replan_s=0.5, planner_replan_s={"letspi-fast": 0.2, "slow": 2.0},  # type: ignore[arg-type]
                         dual_rate=DualRateConfig(2.5, 0.4)), b))["identity"]) for b in built}
    # scripted letspi-fast here has no decision step, so the release mode, which changes nothing, is not in its key
    assert released == {"sf": "26c338c8fd692ffe", "letspi-fast": "8035a17c65731a16", "slow": "638c09678f690f04"}
    deciding = build_planners(["letspi-fast"], _options(files, llm_cache=False, prompt_style="choice"))[0]
    assert deciding.planner.holds_presets
    by_release = {mode: planner_evaluation(ClosedLoopConfig(HYBRID, dual_rate=DualRateConfig(2.5, 0.4, release=mode)),  # type: ignore[arg-type]
                                           deciding)["dual_rate"].get("release") for mode in ("off", "checks")}
    assert by_release == {"off": None, "checks": "checks"}

    batch = straight_road_scenario(ego_speed_mps=30.0, neighbours=[VehicleSpec(x0_m=40.0, speed_mps=20.0)],
                                   scenario_id="a")
    digests = scenario_digests(batch)
    assert run_record(batch, digests, "", MetricsConfig(), "open-loop")["key"] == "f141b77a3f11cf06"
    reactive_settings = mode_settings(ClosedLoopConfig(REACTIVE), None)  # type: ignore[arg-type]
    reactive = run_record(batch, digests, "", MetricsConfig(), REACTIVE, reactive_settings)
    assert reactive["key"] == "1da4b636005c9504"
