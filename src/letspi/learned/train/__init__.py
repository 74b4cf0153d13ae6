"""Training of the learned models: the only part of ``letspi.learned`` that imports torch (``letspi[train]``)."""
