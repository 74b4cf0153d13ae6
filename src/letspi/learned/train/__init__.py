"""Training of the learned models (needs torch: ``pip install 'letspi[train]'``, i.e. torch==2.13.0).

Only this subpackage imports torch; inference (``letspi.learned.goal_model``,
``letspi.learned.gnp_model``) is pure NumPy.
"""
