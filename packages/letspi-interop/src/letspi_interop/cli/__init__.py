"""The commands letspi-interop adds to ``letspi`` (through ``letspi_interop.commands``)."""
