"""Modules whose fitted buffers only get their shape when fitted (the layout size is known after ``fit``).

``load_state_dict`` normally refuses a saved tensor whose shape differs from the module's buffer; an
unfitted module holds empty placeholders, so loading adopts the saved shape and dtype instead (on the
module's device). Settings that are not tensors travel in ``get_extra_state`` as plain Python values, so
``torch.load(..., weights_only=True)`` reads the file.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor, nn

__all__ = ["FittedModule", "NotFittedError"]


class NotFittedError(RuntimeError):
    """A fitted module was used before ``fit`` (or ``load_state_dict``)."""


class FittedModule(nn.Module):
    """Base class: ``_fitted_buffers`` names the buffers whose shape (and dtype) loading restores as saved."""

    _fitted_buffers: tuple[str, ...] = ()

    def _load_from_state_dict(self, state_dict: dict[str, Any], prefix: str, *args: Any, **kwargs: Any) -> None:
        for name in self._fitted_buffers:
            saved = state_dict.get(prefix + name)
            if isinstance(saved, Tensor):
                device = self._buffers[name].device
                self._buffers[name] = torch.empty(saved.shape, dtype=saved.dtype, device=device)
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)

    def _set_fitted(self, **tensors: Tensor) -> None:
        """Replace fitted buffers (new shapes allowed; contiguous, as loading makes them), on the module's device."""
        for name, value in tensors.items():
            device = self._buffers[name].device
            self._buffers[name] = value.detach().to(device).clone(memory_format=torch.contiguous_format)
