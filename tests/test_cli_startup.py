"""The command line starts fast: ``letspi --help`` imports no command module, a command imports only its own,
``import letspi.api`` loads no plotting or SciPy; the help lists every command and groups evaluate's options."""

from __future__ import annotations

import importlib.metadata
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

import letspi.cli.app as app_module
from letspi.cli.app import COMMANDS, app, load_command
from letspi.cli.help import first_sentence

ROOT = Path(__file__).resolve().parents[1]
#: what no start-up may load before a command needs it
HEAVY = ("pandas", "pyarrow", "scipy", "matplotlib", "torch", "llama_cpp", "libsumo", "traci", "sumolib", "jinja2",
         "httpx")

PROBE = """
import json, sys
sys.argv = ["letspi", *json.loads(sys.argv[1])]
if sys.argv[1:] == ["-"]:
    import letspi.api
else:
    from letspi.cli.app import main
    try:
        main()
    except SystemExit:
        pass
print(json.dumps(sorted(m for m in sys.modules if m.split(".")[0] in {heavy} or m.startswith("letspi."))))
"""


def _loaded(*args: str) -> set[str]:
    """The modules (heavy third-party ones and letspi's) a fresh process has loaded after ``letspi ARGS``
    (``-``: after ``import letspi.api``)."""
    code = PROBE.replace("{heavy}", repr(set(HEAVY)))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT / "src"), os.environ.get("PYTHONPATH", "")])}
    out = subprocess.run([sys.executable, "-c", code, json.dumps(list(args))], capture_output=True, text=True,
                         env=env, timeout=120)
    assert out.returncode == 0, out.stderr
    return set(json.loads(out.stdout.strip().splitlines()[-1]))


def test_help_loads_no_command_module_and_no_heavy_dependency() -> None:
    loaded = _loaded("--help")
    assert not {m for m in loaded if m.split(".")[0] in HEAVY}, loaded
    assert not {m for m in loaded if m.startswith(("letspi.assembly", "letspi.evaluation", "letspi.viz"))}
    assert "letspi.cli.evaluate" not in loaded and "letspi.cli.data" not in loaded


def test_planners_and_the_api_load_no_plotting_scipy_or_llm_runtime() -> None:
    for args in (("planners",), ("-",)):
        loaded = _loaded(*args)
        assert not {m for m in loaded if m.split(".")[0] in ("scipy", "matplotlib", "torch", "llama_cpp")}, (args, [
            m for m in loaded if m.split(".")[0] in ("scipy", "matplotlib")])
        assert "letspi.viz.report" not in loaded, args
    assert "letspi.cli.data" not in _loaded("planners")  # only the command's own module


def test_every_command_loads_and_the_help_lists_each_once() -> None:
    result = CliRunner().invoke(app, ["--help"], terminal_width=200)
    assert result.exit_code == 0
    listed = [line.split()[0] for line in result.output.split("Commands:")[1].splitlines() if line.strip()]
    assert listed == list(COMMANDS)
    for name, entry in COMMANDS.items():
        command = load_command(name)
        assert command.name == name and hasattr(command, "commands") == (entry.attribute == "app")
        assert entry.summary in result.output and not entry.summary.endswith(".")
    if "export" in COMMANDS:  # letspi-interop installed
        assert "commonroad" in load_command("export").commands  # a group of one sub-command stays a group


def test_a_mistyped_command_gets_a_suggestion() -> None:
    result = CliRunner().invoke(app, ["evalute"])
    assert result.exit_code == 2 and "Did you mean 'evaluate'" in result.output


@pytest.mark.parametrize(("path", "panels"), [
    (("evaluate",), ["Data", "Planners", "Decision step", "LLM", "Closed loop", "Output", "Options"]),
])
def test_evaluate_help_groups_its_options_in_panels(path: tuple[str, ...], panels: list[str]) -> None:
    result = CliRunner().invoke(app, [*path, "--help"], terminal_width=200)
    assert result.exit_code == 0, result.output
    headings = [line[:-1] for line in result.output.splitlines() if line.endswith(":") and not line.startswith(" ")]
    assert headings == panels
    data = result.output.split("Data:")[1].split("Planners:")[0]
    assert "--scenarios" in data and "--limit" in data and "--planner" not in data
    planners = result.output.split("Planners:")[1].split("Decision step:")[0]
    assert "--planner KIND" in planners and "--planner-path DIR" in planners and "--goals" in planners
    assert "package.module:NAME" in planners and "letspi.planners" in planners  # how to name a kind of one's own
    assert "--llm " in result.output.split("LLM:")[1].split("Closed loop:")[0]
    assert "--replan-s" in result.output.split("Closed loop:")[1].split("Output:")[0]


def test_sub_command_summaries_are_whole_sentences() -> None:
    assert first_sentence("Compare two evaluations on the windows both hold (e.g. open vs closed loop). More.") == (
        "Compare two evaluations on the windows both hold (e.g. open vs closed loop)")
    runner = CliRunner()
    for name, entry in COMMANDS.items():
        if entry.attribute != "app":
            continue
        text = runner.invoke(app, [name, "--help"], terminal_width=100).output.split("Commands:")[1]
        assert "..." not in text and "(e.g\n" not in text and not text.rstrip().endswith("(e.g"), (name, text)


def test_a_companion_command_that_is_not_installed_names_its_distribution(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delitem(COMMANDS, "train", raising=False)
    result = CliRunner().invoke(app, ["train", "goals"])
    assert result.exit_code == 2
    assert "letspi-train" in result.output and "pip install -e packages/letspi-train" in result.output


def test_a_distribution_adds_commands_through_the_entry_point_group(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "my_commands.py").write_text(
        "import typer\nfrom letspi.cli.entry import CommandEntry\n"
        "app = typer.Typer()\n"
        "@app.command()\ndef hello(name: str = 'you') -> None:\n    print(f'hello {name}')\n"
        "@app.command()\ndef bye() -> None:\n    print('bye')\n"
        "COMMANDS = {'greet': CommandEntry('my_commands', 'app', 'Greet someone')}\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    ep = importlib.metadata.EntryPoint("my-commands", "my_commands:COMMANDS", app_module.COMMANDS_GROUP)
    monkeypatch.setattr(app_module, "entry_points", lambda group: [ep] if group == app_module.COMMANDS_GROUP else [])
    monkeypatch.setattr(app_module, "COMMANDS", dict(COMMANDS))
    app_module._add_plugin_commands()
    listing = CliRunner().invoke(app, ["--help"], terminal_width=200).output
    assert "greet" in listing and "Greet someone" in listing
    result = CliRunner().invoke(app, ["greet", "hello", "--name", "Ada"])
    assert result.exit_code == 0 and result.output.strip() == "hello Ada"
    # a second distribution may not take a command's name
    with pytest.raises(RuntimeError, match="redefines the command 'greet'"):
        app_module._add_plugin_commands()
