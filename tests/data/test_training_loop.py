"""The training-loop example runs: a DataLoader over a synthetic dataset folder, a tree distance as the loss."""

from __future__ import annotations

import importlib.util
import warnings
from pathlib import Path
from types import ModuleType

import torch

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "training_loop.py"


def _example() -> ModuleType:
    """The example script as a module (it is not in a package)."""
    spec = importlib.util.spec_from_file_location("training_loop", EXAMPLE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_one_step_lowers_the_loss(tmp_path: Path) -> None:
    ex = _example()
    root = ex.make_dataset(tmp_path / "tomato", plants=3, frames=2, T=12)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # float() of a tensor that requires grad, inside registration
        losses = ex.train(root, steps=2, batch_size=3, T=12)
        # the gradient reaches the learnable tensor, and a step along it lowers the loss on the same batch
        ds = ex.TreeSequenceDataset(root, T=12, dtype=torch.float64)
        targets = [seq.frames[len(seq) - 1] for seq in ds]
        template = ds[0].frames[len(ds[0]) - 1]
        offset = torch.zeros_like(template.points, requires_grad=True)
        before = ex.template_loss(template, offset, targets)
        before.backward()
        assert offset.grad is not None and float(offset.grad.abs().max()) > 0
        with torch.no_grad():
            offset -= 0.02 * offset.grad / offset.grad.norm()
        after = ex.template_loss(template, offset.detach(), targets)
    assert len(losses) == 2 and losses[1] < losses[0]
    assert float(after) < float(before)
