"""letspi_train.finetune: training data and models for the LLM planners (physics-verified labels, regressor)."""
