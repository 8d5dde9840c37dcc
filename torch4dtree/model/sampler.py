"""Exact truncated standard normal coefficients (docs/method.md §5, paper §5.3): the generative model's sampler.

Each mode's coefficient is drawn from ``N(0, 1)`` conditioned on ``[-c, c]`` by the inverse CDF: ``u`` uniform on
``[Phi(-c), Phi(c)]``, ``z = Phi^{-1}(u)`` (computed in float64, so ``c`` up to about 8 stays exact), never by
clamping (which would pile mass on the bounds).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor, nn

__all__ = ["TruncatedNormalSampler", "truncated_normal_variance"]


def truncated_normal_variance(c: float) -> float:
    """Variance of the standard normal truncated to ``[-c, c]``: ``1 - 2 c phi(c) / (2 Phi(c) - 1)``."""
    if not c > 0:
        raise ValueError(f"c must be positive, got {c}")
    phi = math.exp(-0.5 * c * c) / math.sqrt(2 * math.pi)
    mass = math.erf(c / math.sqrt(2))
    return 1.0 - 2.0 * c * phi / mass


class TruncatedNormalSampler(nn.Module):
    """Independent standard normal coefficients truncated to ``[-c, c]``, batched.

    Args:
        n_modes: number of coefficients per sample ``m``.
        c: truncation bound (``> 0``; default 3 as in the paper).

    Buffers: ``c ()`` (float64, so ``.to()`` moves it; the samples take the requested dtype).

    Example:
        >>> z = TruncatedNormalSampler(3, c=1.5)(1000, generator=torch.Generator().manual_seed(0))
        >>> z.shape, bool(z.abs().max() <= 1.5)
        (torch.Size([1000, 3]), True)
    """

    def __init__(self, n_modes: int, c: float = 3.0) -> None:
        super().__init__()
        if isinstance(n_modes, bool) or int(n_modes) < 1:
            raise ValueError(f"n_modes must be a positive int, got {n_modes!r}")
        if not (isinstance(c, (int, float)) and math.isfinite(c) and c > 0):
            raise ValueError(f"c must be a positive finite number, got {c!r}")
        self.n_modes = int(n_modes)
        self.register_buffer("c", torch.tensor(float(c), dtype=torch.float64))

    def get_extra_state(self) -> dict:
        return {"version": 1, "n_modes": self.n_modes}

    def set_extra_state(self, state: dict) -> None:
        if not isinstance(state, dict) or state.get("version") != 1:
            raise ValueError("not a TruncatedNormalSampler state")
        self.n_modes = int(state["n_modes"])

    def variance(self) -> float:
        """The per-mode variance of the samples (:func:`truncated_normal_variance`)."""
        return truncated_normal_variance(float(self.c))

    def forward(self, n: int, generator: torch.Generator | None = None, dtype: torch.dtype = torch.float64
                ) -> Tensor:
        """``(n, n_modes)`` coefficients in ``[-c, c]``. The draw depends only on ``generator``'s state (the
        uniforms are drawn on the generator's device, then moved), so a seed gives the same samples on any device
        the module sits on."""
        if isinstance(n, bool) or int(n) < 0:
            raise ValueError(f"n must be a non-negative int, got {n!r}")
        gen_device = generator.device if generator is not None else torch.device("cpu")
        c = float(self.c)
        lo = 0.5 * (1.0 + math.erf(-c / math.sqrt(2)))
        u = torch.rand(int(n), self.n_modes, generator=generator, dtype=torch.float64, device=gen_device)
        p = lo + u * (1.0 - 2.0 * lo)  # uniform on [Phi(-c), Phi(c)] (symmetric)
        z = math.sqrt(2.0) * torch.erfinv(2.0 * p - 1.0)
        return z.clamp(-c, c).to(device=self.c.device, dtype=dtype)  # the clamp only absorbs float rounding
