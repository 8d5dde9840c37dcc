"""Closed-form optimal rotations of SRVFs (Procrustes / Kabsch), batched.

Convention: SRVFs and curves are row vectors, so a rotation ``O (d, d)`` acts as ``q @ O.T``.
Every function returns the ``O`` that maximises ``<q1, O q2> = sum_k q1_k . (O q2_k) / M``.
"""

from __future__ import annotations

import torch
from torch import Tensor

from ..settings import ROTATIONS, check_choice


def check_rotation_mode(rotation: str, d: int) -> None:
    """Raise a ``ValueError`` (:class:`~torch4dtree.trees.TreeError`) for a mode not in ``settings.ROTATIONS`` or
    one that does not fit dimension ``d`` (``"vertical"`` needs 3D).

    Example:
        >>> check_rotation_mode("so3", 2)
        >>> check_rotation_mode("vertical", 2)
        Traceback (most recent call last):
        ...
        ValueError: rotation='vertical' needs 3D curves, got d=2
    """
    check_choice("rotation", rotation, ROTATIONS)
    if rotation == "vertical" and d != 3:
        raise ValueError(f"rotation='vertical' needs 3D curves, got d={d}")


def cross_covariance(q1: Tensor, q2: Tensor) -> Tensor:
    """``A = sum_k q1_k q2_k^T / M``. ``(B, M, d) x (B, M, d) -> (B, d, d)``; ``<q1, O q2> = tr(O A^T)``."""
    return q1.transpose(-1, -2) @ q2 / q1.shape[-2]


def kabsch(A: Tensor) -> Tensor:
    """Proper rotation maximising ``tr(O A^T)``. ``(B, d, d) -> (B, d, d)``; reflections are excluded."""
    U, _, Vh = torch.linalg.svd(A)
    det = torch.linalg.det(U @ Vh)
    # flip the least significant singular direction when U V^T would be a reflection
    D = torch.ones(A.shape[:-1], dtype=A.dtype, device=A.device)
    D[..., -1] = torch.where(det < 0, -1.0, 1.0).to(A.dtype)
    return (U * D.unsqueeze(-2)) @ Vh


def axis_rotation(up: Tensor, angle: Tensor) -> Tensor:
    """Rotations by ``angle (B,)`` about the unit axis ``up (3,)`` (Rodrigues). ``-> (B, 3, 3)``."""
    u = up / up.norm()
    K = torch.zeros(3, 3, dtype=up.dtype, device=up.device)
    K[0, 1], K[0, 2], K[1, 2] = -u[2], u[1], -u[0]
    K = K - K.T
    uu = torch.outer(u, u)
    eye = torch.eye(3, dtype=up.dtype, device=up.device)
    c, s = angle.cos()[:, None, None], angle.sin()[:, None, None]
    return uu + c * (eye - uu) + s * K


def vertical_rotation(A: Tensor, up: Tensor) -> Tensor:
    """Rotation about ``up (3,)`` maximising ``tr(O A^T)``. ``A (B, 3, 3) -> (B, 3, 3)``.

    With ``O = u u^T + cos(t)(I - u u^T) + sin(t) [u]_x`` the objective is
    ``const + cos(t) (tr A - u^T A u) + sin(t) <[u]_x, A>``, maximised by ``atan2``.
    """
    u = (up / up.norm()).to(A.dtype)
    K = torch.zeros(3, 3, dtype=A.dtype, device=A.device)
    K[0, 1], K[0, 2], K[1, 2] = -u[2], u[1], -u[0]
    K = K - K.T
    c = A.diagonal(dim1=-2, dim2=-1).sum(-1) - torch.einsum("i,bij,j->b", u, A, u)
    s = (K * A).sum((-1, -2))
    return axis_rotation(u, torch.atan2(s, c))


def optimal_rotation(q1: Tensor, q2: Tensor, rotation: str = "so3", up: Tensor | None = None) -> Tensor:
    """Optimal ``O`` for ``min ||q1 - O q2||``. ``(B, M, d) x (B, M, d) -> (B, d, d)``.

    ``rotation``: ``"none"`` (identity), ``"vertical"`` (about ``up``, default z, d = 3 only) or
    ``"so3"`` (any proper rotation of R^d).
    """
    B, _, d = q1.shape
    check_rotation_mode(rotation, d)
    if rotation == "none":
        return torch.eye(d, dtype=q1.dtype, device=q1.device).expand(B, d, d).clone()
    A = cross_covariance(q1, q2)
    if rotation == "so3":
        return kabsch(A)
    if up is None:
        up = torch.tensor([0.0, 0.0, 1.0], dtype=q1.dtype, device=q1.device)
    return vertical_rotation(A, up.to(device=q1.device, dtype=q1.dtype))


def random_rotation(B: int, d: int = 3, generator: torch.Generator | None = None,
                    dtype: torch.dtype = torch.float64) -> Tensor:
    """Uniform random proper rotations of R^d (QR of a Gaussian matrix, sign-fixed). ``-> (B, d, d)``."""
    G = torch.randn(B, d, d, generator=generator, dtype=dtype)
    Q, R = torch.linalg.qr(G)
    Q = Q * torch.sign(torch.diagonal(R, dim1=-2, dim2=-1)).unsqueeze(-2)
    flip = torch.linalg.det(Q) < 0
    Q[flip, :, 0] = -Q[flip, :, 0]
    return Q
