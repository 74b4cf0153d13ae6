"""HighD-format recordings of a two-direction highway simulated with SUMO (``generate.generate_highd``); nothing
is imported here, so ``letspi.trafficgen.binaries`` loads alone."""
