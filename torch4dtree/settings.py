"""The package's choices and defaults in one torch-free module.

Every module that validates a choice (rotation, children's positions, hierarchy rule) or needs a default
imports it from here, so a default changes in one place, and the command line can build its help without
importing torch. The measured reasons for each default are in ``docs/method.md`` and ``docs/experiments.md``.
"""

from __future__ import annotations

from collections.abc import Sequence

__all__ = [
    "CROSS_LP", "CROSS_ORDER_TOL", "CROSS_POSITIONS", "DEFAULT_NT", "DEFAULT_POSITIONS", "DEFAULT_T",
    "FALLBACK_ROTATION", "HIERARCHIES", "ORDER_TOL", "POSITIONS", "ROTATIONS", "TIME_WEIGHT", "check_choice",
]

# global rotation searched by a registration: data in one frame, about the up axis, or any (docs/method.md §3)
ROTATIONS = ("none", "vertical", "so3")
# how two trees' matched children are compared: the parent's warp, arc length, or node rank (docs/method.md §3)
POSITIONS = ("warped", "arclength", "rank")
# skeleton -> branch hierarchy: which child continues a branch at a branch point (docs/method.md §2)
HIERARCHIES = ("straightest", "heaviest", "longest")

DEFAULT_T = 64  # points per branch
DEFAULT_POSITIONS = "rank"  # pair registrations
DEFAULT_NT = 32  # common time samples of a trajectory
ORDER_TOL = 0.02  # siblings closer than this share of their parent may match in any order
# cross-sequence registrations (two plants): node ranks, relative lp 12, children kept in order
CROSS_POSITIONS = "rank"
CROSS_LP: float | None = 12.0
CROSS_ORDER_TOL: float | None = ORDER_TOL
FALLBACK_ROTATION: str | None = "vertical"  # tried where the asked rotation finds no better correspondence
TIME_WEIGHT = 1.0  # the temporal registration's weight on the time coordinate


def check_choice(name: str, value: object, choices: Sequence[object]) -> None:
    """Raise a :class:`~torch4dtree.trees.TreeError` naming the setting and its accepted values.

    Example:
        >>> check_choice("rotation", "vertical", ROTATIONS)
        >>> check_choice("rotation", "spin", ROTATIONS)
        Traceback (most recent call last):
        ...
        torch4dtree.trees.structures.TreeError: rotation must be one of ('none', 'vertical', 'so3'), got 'spin'
    """
    if value not in choices:
        from .trees.structures import TreeError  # imported only when there is an error to raise

        raise TreeError(f"{name} must be one of {tuple(choices)}, got {value!r}")
