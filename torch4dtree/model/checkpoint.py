"""Checkpoints of the generative models (docs/method.md §6): one file, readable with
``torch.load(weights_only=True)``, for either :class:`FourDTreeModel` (the paper's) or :class:`OrganModel`.

The file is a dict: ``format`` (:data:`FORMAT` for the paper's model, :data:`ORGAN_FORMAT` for the organ model: it
names the class to rebuild), ``version`` (:data:`VERSION`), ``config`` (the run's settings, free-form JSON-like),
``args`` (the model's settings as a plain dict: :class:`~torch4dtree.settings.ModelSettings` or
:class:`~torch4dtree.settings.OrganSettings` ``.to_dict()``; for the paper's model the flat form with ``positions`` /
``cross_lp`` / ``cross_order_tol`` at the top level loads too) and ``state_dict`` (tensors and plain Python extra
states only). Anything else, including a truncated or corrupt file, raises :class:`CheckpointError` with the path and
what is wrong.
"""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any

import torch

from ..io.files import write_bytes_safely
from ..settings import ModelSettings, OrganSettings
from ..trees.structures import TreeError
from .fourd import FourDTreeModel
from .organs import OrganModel

__all__ = ["FORMAT", "ORGAN_FORMAT", "VERSION", "CheckpointError", "load", "read_checkpoint", "save_model"]

FORMAT = "torch4dtree.FourDTreeModel"
ORGAN_FORMAT = "torch4dtree.OrganModel"
VERSION = 1
# each format, the class it rebuilds and that class's settings
MODEL_CLASSES: dict[str, tuple[type[FourDTreeModel] | type[OrganModel], type[ModelSettings] | type[OrganSettings]]] = {
    FORMAT: (FourDTreeModel, ModelSettings), ORGAN_FORMAT: (OrganModel, OrganSettings)}


class CheckpointError(TreeError):
    """A file that is not a readable torch4dtree model checkpoint."""


def save_model(model: FourDTreeModel | OrganModel, path: str | Path, config: dict[str, Any] | None = None,
               overwrite: bool = False) -> Path:
    """Write ``model`` (fitted, either model) to ``path`` atomically; refuses an existing file unless ``overwrite``.

    Example (a fitted model round-trips: ``load(save_model(model, path)).settings == model.settings``):
        >>> save_model(FourDTreeModel(), "model.pt")
        Traceback (most recent call last):
        ...
        ValueError: the model is not fitted: nothing to save
    """
    fmt = next((name for name, (cls, _) in MODEL_CLASSES.items() if isinstance(model, cls)), None)
    if fmt is None:
        raise TypeError(f"expected a FourDTreeModel or an OrganModel, got {type(model).__name__}")
    if not model.is_fitted:
        raise ValueError("the model is not fitted: nothing to save")
    state = {k: v.detach().cpu() if isinstance(v, torch.Tensor) else v for k, v in model.state_dict().items()}
    payload = {"format": fmt, "version": VERSION, "config": dict(config or {}), "args": model.settings.to_dict(),
               "state_dict": state}
    buf = io.BytesIO()
    torch.save(payload, buf)
    return write_bytes_safely(Path(path), buf.getvalue(), overwrite=overwrite)


def read_checkpoint(path: str | Path) -> dict[str, Any]:
    """The checkpoint dict, validated (format, version, fields)."""
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"{path}: no such checkpoint file")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # noqa: BLE001 - any unpickling failure means the same thing to the user
        raise CheckpointError(f"{path}: not a readable torch4dtree checkpoint (truncated, corrupt or another "
                              f"format: {type(e).__name__})") from None
    if not isinstance(payload, dict) or payload.get("format") not in MODEL_CLASSES:
        raise CheckpointError(f"{path}: a torch file, but not a torch4dtree model checkpoint (format "
                              f"{payload.get('format') if isinstance(payload, dict) else type(payload).__name__!r})")
    if payload.get("version") != VERSION:
        raise CheckpointError(f"{path}: checkpoint format version {payload.get('version')!r}; this torch4dtree "
                              f"reads version {VERSION}")
    for key, kind in (("args", dict), ("state_dict", dict), ("config", dict)):
        if not isinstance(payload.get(key), kind):
            raise CheckpointError(f"{path}: checkpoint field {key!r} is missing or malformed")
    return payload


def load(path: str | Path, map_location: str | torch.device = "cpu") -> FourDTreeModel | OrganModel:
    """Rebuild the model a checkpoint holds (:class:`FourDTreeModel` or :class:`OrganModel`, by its ``format``);
    ``model.checkpoint_config`` holds the run's config.

    Settings saved in the flat form (``registration`` / ``temporal`` dicts, ``positions`` / ``cross_lp`` /
    ``cross_order_tol`` at the top level) are rebuilt as :class:`~torch4dtree.settings.ModelSettings`.

    Example:
        >>> load("no/such/model.pt")
        Traceback (most recent call last):
        ...
        torch4dtree.model.checkpoint.CheckpointError: no/such/model.pt: no such checkpoint file
    """
    payload = read_checkpoint(path)
    try:
        cls, settings = MODEL_CLASSES[payload["format"]]
        model = cls(settings.from_dict(payload["args"]))
        model.load_state_dict(payload["state_dict"])
    except (TypeError, ValueError, KeyError, RuntimeError) as e:
        raise CheckpointError(f"{path}: the checkpoint does not rebuild a model ({type(e).__name__}: {e})") from None
    model.checkpoint_config = payload["config"]
    return model.to(map_location)
