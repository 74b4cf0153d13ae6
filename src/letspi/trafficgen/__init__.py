"""HighD-format recordings of a two-direction highway simulated with SUMO; entry point
``letspi.trafficgen.generate.generate_highd``. Nothing is imported here: a module that needs only the SUMO
binaries (``letspi.trafficgen.binaries``) does not load the generator."""
