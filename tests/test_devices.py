"""The differentiable tensor ops keep tensors on their device: run on PyTorch's ``meta`` device, which has no
data, any hidden ``.cpu()`` / ``.numpy()`` / ``.item()`` round trip fails. (No GPU is available to the project;
this is what can be checked without one.)"""

import pytest
import torch

from torch4dtree.curves import (
    curve_length,
    identity_warp,
    interpolate_curve,
    inverse_srvf,
    optimal_rotation,
    srvf,
    srvf_inner,
    srvf_sq_norm,
    warp_curve,
    warp_energy,
    warp_srvf,
)

META = torch.device("meta")


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_curve_ops_stay_on_the_device(dtype):
    x = torch.empty(4, 20, 3, device=META, dtype=dtype)
    g = identity_warp(4, 20, x)
    up = torch.empty(3, device=META, dtype=dtype)
    q = srvf(x)
    outputs = {
        "srvf": q, "inverse_srvf": inverse_srvf(q), "warp_srvf": warp_srvf(q, g), "warp_curve": warp_curve(x, g),
        "interpolate_curve": interpolate_curve(x, g), "srvf_sq_norm": srvf_sq_norm(q), "curve_length": curve_length(x),
        "srvf_inner": srvf_inner(q, q), "warp_energy": warp_energy(q, q, g), "identity_warp": g,
        "optimal_rotation so3": optimal_rotation(q, q, "so3"),
        "optimal_rotation vertical": optimal_rotation(q, q, "vertical", up),
    }
    for name, y in outputs.items():
        assert y.device == META and y.dtype == dtype, name
    assert outputs["inverse_srvf"].shape == x.shape and outputs["warp_srvf"].shape == q.shape
