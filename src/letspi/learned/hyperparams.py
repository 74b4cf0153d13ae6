"""Training hyperparameters of the goal predictor and GNP (torch-free: the CLI reads its defaults here)."""

from __future__ import annotations

from dataclasses import dataclass, field

from letspi.learned.layers import EncoderConfig


@dataclass(frozen=True)
class GoalTrainConfig:
    epochs: int = 40
    batch_size: int = 128
    lr: float = 2e-3
    weight_decay: float = 1e-4
    n_goals: int = 6
    cls_weight: float = 1.0
    center_weight: float = 1.0
    val_fraction: float = 0.15
    max_train: int | None = None
    seed: int = 0
    threads: int = 1
    encoder: EncoderConfig = field(default_factory=EncoderConfig)


@dataclass(frozen=True)
class GnpTrainConfig:
    epochs: int = 8
    batch_size: int = 64
    lr: float = 1e-3
    weight_decay: float = 1e-4
    collision_weight: float = 1.0
    val_fraction: float = 0.15
    max_train: int | None = 6000
    max_val: int | None = 1000
    neighbour_mode: str = "idm"
    seed: int = 0
    threads: int = 1
    encoder: EncoderConfig = field(default_factory=lambda: EncoderConfig(d_model=32, n_heads=4, n_layers=1, d_ff=64))
