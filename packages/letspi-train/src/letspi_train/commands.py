"""The commands this distribution adds to ``letspi`` (entry-point group ``letspi.commands``)."""

from letspi.cli.entry import CommandEntry

COMMANDS = {
    "fit": CommandEntry("letspi_train.cli.fit", "app", "Fit baseline parameters offline"),
    "train": CommandEntry("letspi_train.cli.train", "app", "Train the learned models and the LLM's adapter"),
}
