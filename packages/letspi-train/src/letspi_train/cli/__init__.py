"""The commands letspi-train adds to ``letspi`` (through ``letspi_train.commands``)."""
