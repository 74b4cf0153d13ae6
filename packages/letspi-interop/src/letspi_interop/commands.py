"""The commands this distribution adds to ``letspi`` (entry-point group ``letspi.commands``)."""

from letspi.cli.entry import CommandEntry

COMMANDS = {
    "export": CommandEntry("letspi_interop.cli.export", "app", "Export scenarios and plans to other tools' formats"),
    "highway-env": CommandEntry("letspi_interop.cli.highway_env", "app",
                                "Run planners in highway-env episodes and export them as HighD"),
}
