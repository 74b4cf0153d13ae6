"""letspi's self-benchmarks (speed, robustness, Ctrl-C) and the references they compare against; run from the
repository: ``python -m benchmarks.speed --help``. Not part of the installed package."""
