"""The table of planner kinds: every kind resolves, builds and lists from one entry, and keys do not move."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from letspi.assembly import resolve
from letspi.assembly.planner_table import BUILT_IN, FutureUse
from letspi.assembly.planners import resolve_planner
from letspi.assembly.resolve import Resolver
from letspi.cli.app import app
from letspi.method.memory import MemoryBank
from letspi.physics.params import SocialForceParams
from letspi.planners.cv import CvConfig
from letspi.planners.idm import IdmConfig
from letspi.planners.options import PlannerOptions
from letspi.planners.sf_params import save_sf_params

ALL_KINDS = ("human", "cv", "idm", "sf", "sf-opt", "sf-check", "gnp", "frenet", "mlp", "llm", "letspi-memory",
             "letspi-fast", "letspi-fs")


def _name_sha(path: object) -> str:
    return hashlib.sha256(Path(str(path)).name.encode()).hexdigest()


@pytest.fixture
def pinned_options(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> PlannerOptions:
    """Options whose fingerprints do not depend on shipped data: weights, model files and prompt text are
    fingerprinted by their name, the parameters are the code defaults and the memory bank is empty."""
    monkeypatch.setattr(resolve, "load_weights", lambda *args, **kwargs: None)
    monkeypatch.setattr(resolve, "weights_sha256", _name_sha)
    monkeypatch.setattr(resolve, "file_sha256", _name_sha)
    monkeypatch.setattr(resolve, "prompt_sha256", lambda: "p" * 64)
    params = save_sf_params(tmp_path / "sf.json", SocialForceParams(), {}, {})
    MemoryBank.open(tmp_path / "memory.sqlite").close()
    return PlannerOptions(sf_params_file=params, memory=tmp_path / "memory.sqlite", mlp_weights=tmp_path / "mlp")


VARIANT = {"neighbour_mode": "constant_velocity", "top_k": 5, "shield": False, "max_iterations": 1,
           "goal_adjustment": False, "allow_same_vehicle": True, "memory_fraction": 0.5, "llm": "scripted:default",
           "fast_llm": "scripted:default", "prompt_style": "compact"}
#: Keys computed on main at ea22160, before the table existed: results directories and memory banks are
#: keyed by them, so moving configuration classes must not move a key. The LLM planners' keys moved once,
#: on purpose, when ``LlmConfig`` gained ``runtime`` (llama.cpp version and flash attention change answers), and
#: the default ones again when the fine-tuned model became the default (its adapter and the compact prompt),
#: and again when issue 28's choice model shipped (its manifest's prompt style choice turns the decision step on),
#: and again when the embedded base ran from its F16 copy (another file) and the fast phase verified its choice.
#: letspi-fast and sf-check moved once more (issue 36) when the shield stopped replacing the presets the decision
#: step planned (``shield_presets`` False in their key; ``--shield-presets`` gives the old key), and letspi-fast and
#: letspi-fs again when the verification of the model's choice went off by default (``--verify`` gives the old key).
PINNED_KEYS = {
    "human": "70ac28e00fca6bcb", "cv": "7e67bce47ff4cc19", "idm": "6be513ccf5f29f87", "sf": "450d00b28c1d1035",
    "sf-opt": "9ca84b4faa1546e9", "gnp": "3ed102fddba73923", "mlp": "ecfea6602f3bd4b0", "llm": "534f43ea8a81abfb",
    "letspi-memory": "2c0af099e7a4eb86", "letspi-fast": "b7eccc117e628800", "letspi-fs": "d81fa564a9f6caa5",
    # frenet moved on the frenet2 branch on purpose: new settings (braking candidates, following terms, the
    # cautious check, the start-deceleration limit) and weights (k_headway, k_rss) are in its key
    "frenet": "fe73b79fa4e18c4a",
    # issue 28: the decision step without a model; its key holds the shipped presets and risk model's SHA-256
    "sf-check": "aa410e221fe5b15a",
}
PINNED_VARIANT_KEYS = {
    "human": "70ac28e00fca6bcb", "cv": "7e67bce47ff4cc19", "idm": "7ebf8bb605573595", "sf": "a767eb08059b212e",
    "sf-opt": "965ba2e5f5e7da6d", "gnp": "6a4d2b27689d4ea6", "mlp": "91a70a3ac82050db", "llm": "8b044cb7aa3fbaa4",
    "letspi-memory": "b990114e7952b187", "letspi-fast": "27ae453b4559b8a3", "letspi-fs": "0d959d74e5b9deb0",
    "frenet": "428520381f961d0c",  # moved on frenet2 (see PINNED_KEYS)
    "sf-check": "050b9ad37f8fcf68",
}
#: default: moved with the choice model (issue 28) and with the F16 copy of the base (another file name)
PINNED_COLLECTION_KEYS = {"default": "a1609d159281757d", "variant": "48dba622cf863542"}


def _keys(options: PlannerOptions) -> dict[str, str]:
    return {kind: resolve_planner(kind, options, env={}).key() for kind in ALL_KINDS}


def test_configuration_keys_did_not_move(pinned_options: PlannerOptions) -> None:
    variant = pinned_options.replace(**VARIANT)
    assert _keys(pinned_options) == PINNED_KEYS
    assert _keys(variant) == PINNED_VARIANT_KEYS
    assert {"default": Resolver(pinned_options, env={}).memory_phase().key(),
            "variant": Resolver(variant, env={}).memory_phase().key()} == PINNED_COLLECTION_KEYS
    verified = pinned_options.replace(verify=True)  # the keys while the verification was on by default
    assert {k: resolve_planner(k, verified, env={}).key() for k in ("letspi-fast", "letspi-fs")} == {
        "letspi-fast": "654284dc2c1d38c4", "letspi-fs": "709a0d6688cf5124"}
    # the shield on the planned presets too: the keys (and results) of before issue 36
    old_shield = verified.replace(shield_presets=True)
    assert {k: resolve_planner(k, old_shield, env={}).key() for k in ("letspi-fast", "sf-check")} == {
        "letspi-fast": "5918ff434343a9fe", "sf-check": "4dba20068bdd2d5d"}


def test_every_kind_has_one_entry_and_the_kinds_derive_from_it() -> None:
    assert BUILT_IN.names == ALL_KINDS
    assert len({kind.name for kind in BUILT_IN.kinds}) == len(BUILT_IN.kinds)
    for kind in BUILT_IN.kinds:
        # the configuration class can stand for this kind (its `kind` literal admits the name)
        assert kind.config_class.model_fields["kind"].annotation.__args__.count(kind.name) == 1, kind.name
    with pytest.raises(ValueError, match=r"unknown planner 'sf-cv'; did you mean sf-check\? \(available: human, cv, "
                                         r".*, letspi-fs; a kind of your own: --planner package.module:NAME"):
        resolve_planner("sf-cv", PlannerOptions(), table=BUILT_IN)  # installed kinds (CI's example) follow
    with pytest.raises(ValueError, match=r"unknown planner 'sff'; did you mean sf\? "):
        resolve_planner("sff", PlannerOptions(), table=BUILT_IN)
    with pytest.raises(ValueError, match=r"unknown planner 'zzz' \(available"):  # nothing close: no guess
        resolve_planner("zzz", PlannerOptions(), table=BUILT_IN)


def test_records_parse_back_into_their_configuration_class(pinned_options: PlannerOptions) -> None:
    for kind in ALL_KINDS:
        config = resolve_planner(kind, pinned_options, env={})
        again = BUILT_IN.parse_config(json.loads(json.dumps(config.record())))
        assert type(again) is type(config) and again == config and again.key() == config.key(), kind
    with pytest.raises(ValueError, match="does not match any of the expected tags"):
        BUILT_IN.parse_config({"kind": "apollo-lattice"})


def test_reads_future_follows_the_oracle_inputs(pinned_options: PlannerOptions) -> None:
    """``human`` always reads the recorded future, ``cv`` never; the others when their goals or neighbour
    prediction are oracles (``gnp`` and ``mlp`` refuse the oracle neighbours at resolution)."""
    def future(kind: str, **options: str) -> bool | str:
        try:
            return BUILT_IN.reads_future(resolve_planner(kind, pinned_options.replace(**options), env={}))
        except ValueError as exc:
            return "refused" if "predicted neighbours" in str(exc) or "learned goal" in str(exc) else str(exc)

    assert {k: future(k) for k in ALL_KINDS} == {k: k == "human" for k in ALL_KINDS}
    with_oracle_goals = {k: future(k, goals="oracle") for k in ALL_KINDS}
    assert with_oracle_goals == {**{k: True for k in ALL_KINDS}, "cv": False, "idm": False, "gnp": "refused"}
    with_oracle_neighbours = {k: future(k, neighbour_mode="ground_truth_oracle") for k in ALL_KINDS}
    assert with_oracle_neighbours == {**{k: True for k in ALL_KINDS}, "cv": False, "gnp": "refused",
                                      "mlp": "refused"}
    assert BUILT_IN.kind("human").future is FutureUse.ALWAYS and BUILT_IN.kind("cv").future is FutureUse.NEVER


def test_a_configuration_of_the_wrong_class_is_refused() -> None:
    wrong = CvConfig.model_construct(kind="idm")  # type: ignore[call-arg]
    with pytest.raises(TypeError, match="expects IdmConfig"):
        BUILT_IN.reads_future(wrong)
    assert not BUILT_IN.reads_future(IdmConfig())


def test_letspi_planners_lists_every_kind() -> None:
    runner = CliRunner()
    listing = runner.invoke(app, ["planners", "--json"])
    assert listing.exit_code == 0, listing.output
    rows = json.loads(listing.output)
    built_in = [row["kind"] for row in rows if row["source"] == "built in"]  # then installed kinds (CI's example)
    assert built_in == list(ALL_KINDS) == [row["kind"] for row in rows][: len(ALL_KINDS)]
    assert {row["kind"]: row["reads_future"] for row in rows}["human"] == FutureUse.ALWAYS.value
    assert all(row["description"] for row in rows)
    text = runner.invoke(app, ["planners"])
    assert text.exit_code == 0 and all(kind in text.output for kind in ALL_KINDS)
    help_text = runner.invoke(app, ["evaluate", "--help"], terminal_width=400).output
    assert "mlp" in help_text and "letspi-fs" in help_text  # the --planner help is derived from the table
