"""torch4dtree in a PyTorch training loop: a ``DataLoader`` over a folder of 4D trees, a tree distance as the loss.

The registered distance between two trees (docs/method.md §3) is differentiable in the points of
the trees given the registration's discrete choices (which branches match, in which order), so it
can train any tensor that makes a tree. Here the learnable tensor is an offset of every point of
a *template* tree, and the loss is the mean squared distance from the template to the last frame
of every 4D tree of a batch: gradient descent moves the template towards their mean shape (a
Karcher mean, docs/method.md §4, found by an optimiser instead of the package's solver).

Run::

    python examples/training_loop.py [--plants 4] [--steps 5] [--out DIR]

It writes a small synthetic dataset folder (the format of ``torch4dtree synth``), reads it back
through :class:`~torch4dtree.data.dataset.TreeSequenceDataset` and prints the loss per step.
"""

from __future__ import annotations

import argparse
import tempfile
from dataclasses import replace
from pathlib import Path

import torch
from torch.utils.data import DataLoader

from torch4dtree.data import synthetic_dataset, write_dataset
from torch4dtree.data.dataset import TreeSequenceDataset, collate_sequences
from torch4dtree.trees.registration import register_trees
from torch4dtree.trees.structures import Trees


def make_dataset(root: Path, plants: int = 4, frames: int = 3, T: int = 16, seed: int = 0) -> Path:
    """Write ``plants`` synthetic tomato plants of ``frames`` scans as a dataset folder ``root``; returns it."""
    return write_dataset(synthetic_dataset("tomato", plants=plants, seed=seed, n_frames=frames, T=T), root)


def template_loss(template: Trees, offset: torch.Tensor, targets: list[Trees]) -> torch.Tensor:
    """Mean squared registered distance from ``template`` moved by ``offset (N, T, 3)`` to each single tree."""
    moving = replace(template, points=template.points + offset)
    return torch.stack([register_trees(moving, target).distance ** 2 for target in targets]).mean()


def train(root: Path, steps: int = 5, lr: float = 0.05, batch_size: int = 2, T: int = 16) -> list[float]:
    """Fit the template's offset to the last frames of the dataset's 4D trees; returns the loss of every step.

    Each step is one pass over the ``DataLoader`` (one optimiser step per batch); the loss reported
    for a step is the mean of its batches' losses before their updates.
    """
    dataset = TreeSequenceDataset(root, T=T, dtype=torch.float64)
    loader = DataLoader(dataset, batch_size=batch_size, shuffle=False, collate_fn=collate_sequences)
    template = dataset[0].frames[len(dataset[0]) - 1]  # start from one plant's last scan
    offset = torch.zeros_like(template.points, requires_grad=True)
    optimiser = torch.optim.Adam([offset], lr=lr)
    losses = []
    for _ in range(steps):
        total = 0.0
        for batch in loader:  # batch.points (B, F, N, T, 3) and masks; batch.sequences: the 4D trees
            targets = [seq.frames[len(seq) - 1] for seq in batch.sequences]
            optimiser.zero_grad()
            loss = template_loss(template, offset, targets)
            loss.backward()
            optimiser.step()
            total += float(loss) * len(targets)
        losses.append(total / len(dataset))
    return losses


def main() -> None:
    """Command line: write the dataset (to a temporary folder unless ``--out``), train, print the losses."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--plants", type=int, default=4)
    parser.add_argument("--steps", type=int, default=5)
    parser.add_argument("--out", type=Path, default=None, help="dataset folder to write (must not exist)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        root = make_dataset(args.out or Path(tmp) / "tomato", plants=args.plants)
        for step, loss in enumerate(train(root, steps=args.steps)):
            print(f"step {step}: mean squared distance {loss:.4f}")


if __name__ == "__main__":
    main()
