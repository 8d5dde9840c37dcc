"""Settings shared by the commands, as a dataclass that a small JSON file can override.

``configs/`` holds one file per kind of data (tomato, maize, neurons). Unknown keys are errors,
so a typo never silently falls back to a default. This module imports neither torch nor the tree
code at import time, so the command line can build its help without them.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path

ROTATIONS = ("none", "vertical", "so3")
# the settings that decide how files become trees (the fields of io.LoadOptions that a config sets)
LOAD_SETTINGS = ("T", "max_layers", "min_branch_length", "repair", "hierarchy", "joint_hierarchy")
# = trees.skeleton.HIERARCHIES (literal for the same reason as DEFAULT_T; tested)
HIERARCHIES = ("straightest", "heaviest", "longest")
# = trees.registration.POSITIONS / DEFAULT_POSITIONS and temporal.spatiotemporal.CROSS_POSITIONS / CROSS_LP /
# CROSS_ORDER_TOL (literal, tested)
POSITIONS = ("warped", "arclength", "rank")
DEFAULT_POSITIONS = "rank"
CROSS_POSITIONS = "rank"
CROSS_LP: float | None = 12.0
CROSS_ORDER_TOL: float | None = 0.02
# = trees.structures.DEFAULT_T (kept literal so that importing this module never imports torch; tested)
DEFAULT_T = 64


def _error(message: str) -> ValueError:
    """A :class:`~torch4dtree.trees.structures.TreeError` (imported only when there is an error to raise)."""
    from .trees.structures import TreeError

    return TreeError(message)



@dataclass
class Config:
    """Loading and registration settings (SPEC §2, §3)."""

    T: int = DEFAULT_T
    max_layers: int | None = None
    min_branch_length: float = 0.0
    repair: bool = False
    hierarchy: str = "straightest"  # skeleton -> branches rule (torch4dtree.trees.skeleton)
    joint_hierarchy: bool = True  # SWC sequences: main branches that agree over time (torch4dtree.trees.growth)
    rotation: str = "none"
    lambdas: tuple[float, float, float] = (1.0, 1.0, 1.0)  # (lm, ls, lp)
    neighbourhood: int = 4  # DP slopes up to 4: fastest and most cycle-consistent on Pheno4D at T = 64
    # how two trees' children are compared in pair registrations (torch4dtree register); the Karcher mean and the
    # tree space register with "warped" (their layout's metric), cross-sequence registrations with cross_positions
    positions: str = DEFAULT_POSITIONS
    # cross-sequence registrations (register4d, the model's population): children's positions, relative lp
    # (null: lambdas[2]) and order tolerance (null: children matched in any order); within a sequence,
    # register_sequence keeps its own (temporal.spatiotemporal.CROSS_*)
    cross_positions: str = CROSS_POSITIONS
    cross_lp: float | None = CROSS_LP
    cross_order_tol: float | None = CROSS_ORDER_TOL
    # the generative model (SPEC §5; torch4dtree.model.FourDTreeModel)
    n_t: int = 32  # common time samples of the trajectories
    tree_components: int | None = None  # tree-PCA components (None: the share tree_variance)
    tree_variance: float = 0.99
    modes: int | None = None  # trajectory-PCA modes (None: the share mode_variance)
    mode_variance: float = 0.95
    c: float = 3.0  # sampler truncation: coefficients in [-c, c]
    medoid_candidates: int = 3  # candidates for the population's reference 4D tree
    mean_iters: int = 10  # rounds of the 4D Karcher mean
    render_size: int = 256  # pixels per cell of the figures and videos
    notes: str = field(default="", compare=False)

    def __post_init__(self) -> None:
        if self.T < 2:
            raise _error(f"T must be at least 2, got {self.T}")
        if self.hierarchy not in HIERARCHIES:
            raise _error(f"hierarchy must be one of {HIERARCHIES}, got {self.hierarchy!r}")
        if self.rotation not in ROTATIONS:
            raise _error(f"rotation must be one of {ROTATIONS}, got {self.rotation!r}")
        self.lambdas = tuple(float(x) for x in self.lambdas)  # type: ignore[assignment]
        if len(self.lambdas) != 3 or min(self.lambdas) < 0 or min(self.lambdas[:2]) <= 0:
            raise _error(f"lambdas must be (lm > 0, ls > 0, lp >= 0), got {self.lambdas}")
        if self.positions not in POSITIONS:
            raise _error(f"positions must be one of {POSITIONS}, got {self.positions!r}")
        if self.cross_positions not in POSITIONS:
            raise _error(f"cross_positions must be one of {POSITIONS}, got {self.cross_positions!r}")
        for name in ("cross_lp", "cross_order_tol"):
            value = getattr(self, name)
            if value is not None:
                if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 <= value < float("inf"):
                    raise _error(f"{name} must be null or a finite number >= 0, got {value!r}")
                setattr(self, name, float(value))
        if self.neighbourhood < 1:
            raise _error(f"neighbourhood must be at least 1, got {self.neighbourhood}")
        self._check_model_settings()

    def _check_model_settings(self) -> None:
        for name in ("n_t", "medoid_candidates", "mean_iters", "render_size"):
            if getattr(self, name) < (2 if name == "n_t" else 1):
                raise _error(f"{name} must be at least {2 if name == 'n_t' else 1}, got {getattr(self, name)}")
        for name in ("tree_components", "modes"):
            if getattr(self, name) is not None and getattr(self, name) < 1:
                raise _error(f"{name} must be null or at least 1, got {getattr(self, name)}")
        for name in ("tree_variance", "mode_variance"):
            if not 0 < getattr(self, name) <= 1:
                raise _error(f"{name} must be in (0, 1], got {getattr(self, name)}")
        if not self.c > 0:
            raise _error(f"c must be positive, got {self.c}")

    def model_args(self) -> dict:
        """The :class:`~torch4dtree.model.FourDTreeModel` constructor arguments these settings give."""
        return {"lambdas": list(self.lambdas), "rotation": self.rotation, "n_t": self.n_t,
                "tree_components": self.tree_components, "tree_variance": self.tree_variance,
                "medoid_candidates": self.medoid_candidates, "registration": {"neighbourhood": self.neighbourhood},
                "modes": self.modes, "mode_variance": self.mode_variance, "c": self.c, "mean_iters": self.mean_iters,
                **self.cross_args()}

    def load_options(self):  # noqa: ANN201 - io.LoadOptions (io imports structures; keep this module light)
        """The :class:`~torch4dtree.io.LoadOptions` with every setting the two share taken from here."""
        from .io import LoadOptions

        return LoadOptions(**{name: getattr(self, name) for name in LOAD_SETTINGS})

    def cross_args(self) -> dict:
        """The cross-sequence registration settings as :func:`~torch4dtree.temporal.register4d` takes them."""
        return {"positions": self.cross_positions, "cross_lp": self.cross_lp, "cross_order_tol": self.cross_order_tol}

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


def load_config(path: str | Path) -> Config:
    """Read a JSON config; keys not listed in :class:`Config` are rejected with their name."""
    path = Path(path)
    try:
        raw = json.loads(path.read_text())
    except (OSError, ValueError) as e:
        raise _error(f"{path}: cannot read the config ({e})") from None
    if not isinstance(raw, dict):
        raise _error(f"{path}: a config is a JSON object of settings")
    known = {f.name for f in dataclasses.fields(Config)}
    unknown = sorted(set(raw) - known)
    if unknown:
        raise _error(f"{path}: unknown setting(s) {unknown}; known: {sorted(known)}")
    try:
        return Config(**raw)
    except (TypeError, ValueError) as e:  # TreeError is a ValueError; TypeError: a value of the wrong kind
        raise _error(f"{path}: {e}") from None
