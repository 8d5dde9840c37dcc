"""The paper's timings (Khanam et al., ECCV 2024; MATLAB, unspecified CPU), beside which ``torch4dtree evaluate``
and ``torch4dtree benchmark`` report ours. One place, so that every report quotes the same figure.

Example:
    >>> SECONDS["register_3d"] / 0.046  # the speed-up of a 46 ms registration of two 3D trees
    50.0

The paper's tables of distances and errors stand in the experiment that reproduces each (:mod:`.spatial`: Tables 1
and 2, :mod:`.temporal`: Table 3).
"""

from __future__ import annotations

__all__ = ["SECONDS"]

# seconds per operation
SECONDS: dict[str, float] = {
    "register_3d": 2.3,  # register two 3D trees
    "register_4d_tomato": 235.0,  # spatially register two 4D tomato plants
    "register_4d_maize": 17.0,  # the same, maize
    "temporal_maize": 0.006,  # one temporal registration (Fig. 2), maize
    "temporal_tomato": 0.037,  # the same, tomato
    "geodesic_4d": 0.025,  # a 4D geodesic
    "mean_4d": 0.0006,  # the mean of seven registered 4D tomato plants (Fig. 6)
    "sample": 0.0001,  # generate one 4D tomato plant (Fig. 7)
    "tomato_spatial_all": 270.0,  # the reference scripts' "4-5 minutes" for every tomato spatial registration
}
