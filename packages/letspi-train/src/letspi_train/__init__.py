"""letspi-train: training and fitting of letspi's shipped weights (``letspi train``, ``letspi fit``)."""
