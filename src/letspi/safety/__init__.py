"""letspi.safety: safety checks of candidate plans against *predicted* neighbours (what a planner may
know at t = 0). Used by the ``sf-opt`` planner and LetsPi's reflection module alike, so a plan the
reflection accepts is one ``sf-opt`` would accept too. The evaluation scores plans against the recorded
futures instead (``letspi.metrics``)."""
