"""letspi-interop: letspi with highway-env (episodes, suites, reports) and CommonRoad (export)."""
