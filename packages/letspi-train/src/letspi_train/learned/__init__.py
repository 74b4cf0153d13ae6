"""Training of the learned models: the torch side of ``letspi.learned``."""
