"""Safety checks of candidate plans against *predicted* neighbours (what a planner may know at t = 0), shared by
``sf-opt``, reflection and the shield; the evaluation scores against the recorded futures (``letspi.metrics``)."""
