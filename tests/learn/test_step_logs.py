"""``logs_this_step``: a module that skips ``self.log`` on the steps whose values Lightning would drop writes the same
CSV log as one that logs every step (the logger's cadence, the step budget's last step, an early stop)."""

from __future__ import annotations

import lightning as L
import pytest
import torch
from torch.utils.data import DataLoader, TensorDataset

from blenav.learn.common.trainer import StepBudget, logs_this_step


class _Tiny(L.LightningModule):
    def __init__(self, skip: bool):
        super().__init__()
        self.lin, self.skip = torch.nn.Linear(3, 2), skip

    def training_step(self, batch, batch_idx):
        loss = ((self.lin(batch[0]) - batch[1]) ** 2).mean()
        if not self.skip or logs_this_step(self._trainer):
            self.log("train/loss", loss.detach(), batch_size=4)
            self.log("train/step", float(self.global_step), batch_size=4)
        return loss

    def configure_optimizers(self):
        return torch.optim.SGD(self.parameters(), lr=0.01)


def _csv(tmp_path, skip: bool, steps: int, every: int) -> str:
    g = torch.Generator().manual_seed(3)
    data = TensorDataset(torch.randn(28, 3, generator=g), torch.randn(28, 2, generator=g))  # 7 batches an epoch
    torch.manual_seed(0)
    module = _Tiny(skip)
    out = tmp_path / ("skip" if skip else "all")
    logger = L.pytorch.loggers.CSVLogger(out, name="logs", version=0)
    trainer = L.Trainer(max_epochs=-1, callbacks=[StepBudget(steps)], logger=logger, log_every_n_steps=every,
                        enable_progress_bar=False, enable_checkpointing=False, enable_model_summary=False,
                        accelerator="cpu")
    trainer.fit(module, DataLoader(data, batch_size=4))
    assert trainer.global_step == steps
    return (out / "logs" / "version_0" / "metrics.csv").read_text()


@pytest.mark.parametrize("steps, every", [(17, 4)])  # the budget ends between two logged steps
def test_skipping_the_dropped_steps_writes_the_same_log(tmp_path, steps, every):
    full, skipped = _csv(tmp_path, False, steps, every), _csv(tmp_path, True, steps, every)
    assert skipped == full
    rows = full.strip().splitlines()[1:]
    assert len(rows) == steps // every + (steps % every != 0)  # every n-th step and the budget's last one


def test_outside_a_fit_every_step_logs():
    assert logs_this_step(None)
