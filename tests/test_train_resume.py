"""Resumable step training (letspi_train.learned.loop.run_steps): a run killed after a checkpoint and
started again ends with exactly the weights and losses of an unbroken run; another run's checkpoint
is refused."""

from __future__ import annotations

from pathlib import Path

import pytest

torch = pytest.importorskip("torch")

pytest.importorskip("letspi_train", reason="letspi-train is not installed (pip install -e packages/letspi-train)")
from letspi_train.learned.loop import (  # noqa: E402
    CHECKPOINT_FILE,
    CheckpointMismatchError,
    checkpoint_step,
    run_steps,
)

N_TRAIN = 40


class Killed(Exception):
    pass


def _problem(seed: int = 0) -> tuple[torch.nn.Linear, torch.Tensor, torch.Tensor]:
    gen = torch.Generator().manual_seed(123)
    x = torch.randn(N_TRAIN, 3, generator=gen)
    y = x @ torch.tensor([[1.0], [-2.0], [0.5]]) + 0.1 * torch.randn(N_TRAIN, 1, generator=gen)
    torch.manual_seed(seed)
    return torch.nn.Linear(3, 1), x, y


def _train(out: Path | None, kill_after: int | None = None, fingerprint: dict[str, object] | None = None,
           total: int = 60) -> tuple[torch.nn.Linear, list[float]]:
    net, x, y = _problem()

    def loss(idx: list[int]) -> torch.Tensor:
        return ((net(x[idx]) - y[idx]) ** 2).mean()

    def progress(step: int, _total: int, _loss: float) -> None:
        if kill_after is not None and step == kill_after:
            raise Killed

    history = run_steps(net, list(net.parameters()), n_train=N_TRAIN, total_steps=total, batch_size=8, lr=0.3,
                        weight_decay=0.0, seed=7, batch_loss=loss, lr_factor=lambda s: 1.0 / (1 + 0.05 * s),
                        trainable_state=lambda: {k: v.detach().clone() for k, v in net.state_dict().items()},
                        load_trainable_state=net.load_state_dict, checkpoint_dir=out, checkpoint_every_s=0.0,
                        fingerprint=fingerprint or {"data": "a"}, progress=progress)
    return net, history.losses


def test_killed_run_resumes_to_the_unbroken_result(tmp_path: Path) -> None:
    unbroken, losses = _train(None)
    assert losses[-1] < losses[0] / 5  # it learns
    with pytest.raises(Killed):
        _train(tmp_path, kill_after=23)
    assert (tmp_path / CHECKPOINT_FILE).is_file()
    state = torch.load(tmp_path / CHECKPOINT_FILE, weights_only=False)
    assert state["step"] == 22  # saved after every step but the one interrupted in its callback
    assert checkpoint_step(tmp_path) == 22 and checkpoint_step(tmp_path / "none") == 0  # Ctrl-C's count
    resumed, resumed_losses = _train(tmp_path)
    assert resumed_losses == pytest.approx(losses, abs=0, rel=1e-6)
    for a, b in zip(unbroken.parameters(), resumed.parameters(), strict=True):
        assert torch.allclose(a, b, atol=1e-7)


def test_a_checkpoint_of_another_run_is_refused(tmp_path: Path) -> None:
    with pytest.raises(Killed):
        _train(tmp_path, kill_after=5)
    with pytest.raises(CheckpointMismatchError, match="differs in data"):
        _train(tmp_path, fingerprint={"data": "b"})
