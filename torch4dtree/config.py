"""Settings shared by the commands, as a dataclass that a small JSON file can override.

``configs/`` holds one file per kind of data (tomato, maize, neurons). Unknown keys are errors,
so a typo never silently falls back to a default.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path

from .trees.structures import DEFAULT_T, TreeError

ROTATIONS = ("none", "vertical", "so3")
# the settings that decide how files become trees (the fields of io.LoadOptions that a config sets)
LOAD_SETTINGS = ("T", "max_layers", "min_branch_length", "repair", "hierarchy")


@dataclass
class Config:
    """Loading and registration settings (SPEC §2, §3)."""

    T: int = DEFAULT_T
    max_layers: int | None = None
    min_branch_length: float = 0.0
    repair: bool = False
    hierarchy: str = "straightest"  # skeleton -> branches rule (torch4dtree.trees.skeleton.HIERARCHIES)
    rotation: str = "none"
    lambdas: tuple[float, float, float] = (1.0, 1.0, 1.0)  # (lm, ls, lp)
    neighbourhood: int = 4  # DP slopes up to 4: fastest and most cycle-consistent on Pheno4D at T = 64
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
            raise TreeError(f"T must be at least 2, got {self.T}")
        from .trees.skeleton import HIERARCHIES

        if self.hierarchy not in HIERARCHIES:
            raise TreeError(f"hierarchy must be one of {HIERARCHIES}, got {self.hierarchy!r}")
        if self.rotation not in ROTATIONS:
            raise TreeError(f"rotation must be one of {ROTATIONS}, got {self.rotation!r}")
        self.lambdas = tuple(float(x) for x in self.lambdas)  # type: ignore[assignment]
        if len(self.lambdas) != 3 or min(self.lambdas) < 0 or min(self.lambdas[:2]) <= 0:
            raise TreeError(f"lambdas must be (lm > 0, ls > 0, lp >= 0), got {self.lambdas}")
        if self.neighbourhood < 1:
            raise TreeError(f"neighbourhood must be at least 1, got {self.neighbourhood}")
        self._check_model_settings()

    def _check_model_settings(self) -> None:
        for name in ("n_t", "medoid_candidates", "mean_iters", "render_size"):
            if getattr(self, name) < (2 if name == "n_t" else 1):
                raise TreeError(f"{name} must be at least {2 if name == 'n_t' else 1}, got {getattr(self, name)}")
        for name in ("tree_components", "modes"):
            if getattr(self, name) is not None and getattr(self, name) < 1:
                raise TreeError(f"{name} must be null or at least 1, got {getattr(self, name)}")
        for name in ("tree_variance", "mode_variance"):
            if not 0 < getattr(self, name) <= 1:
                raise TreeError(f"{name} must be in (0, 1], got {getattr(self, name)}")
        if not self.c > 0:
            raise TreeError(f"c must be positive, got {self.c}")

    def model_args(self) -> dict:
        """The :class:`~torch4dtree.model.FourDTreeModel` constructor arguments these settings give."""
        return {"lambdas": list(self.lambdas), "rotation": self.rotation, "n_t": self.n_t,
                "tree_components": self.tree_components, "tree_variance": self.tree_variance,
                "medoid_candidates": self.medoid_candidates, "registration": {"neighbourhood": self.neighbourhood},
                "modes": self.modes, "mode_variance": self.mode_variance, "c": self.c, "mean_iters": self.mean_iters}

    def load_options(self):  # noqa: ANN201 - io.LoadOptions (io imports structures; keep this module light)
        """The :class:`~torch4dtree.io.LoadOptions` with every setting the two share taken from here."""
        from .io import LoadOptions

        return LoadOptions(**{name: getattr(self, name) for name in LOAD_SETTINGS})

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


def load_config(path: str | Path) -> Config:
    """Read a JSON config; keys not listed in :class:`Config` are rejected with their name."""
    path = Path(path)
    try:
        raw = json.loads(path.read_text())
    except (OSError, ValueError) as e:
        raise TreeError(f"{path}: cannot read the config ({e})") from None
    if not isinstance(raw, dict):
        raise TreeError(f"{path}: a config is a JSON object of settings")
    known = {f.name for f in dataclasses.fields(Config)}
    unknown = sorted(set(raw) - known)
    if unknown:
        raise TreeError(f"{path}: unknown setting(s) {unknown}; known: {sorted(known)}")
    try:
        return Config(**raw)
    except TreeError as e:
        raise TreeError(f"{path}: {e}") from None


def add_config_arguments(parser: argparse.ArgumentParser, registration: bool = False) -> None:
    """``--config FILE`` and the flags that override it: the loading settings, and with ``registration``
    also ``--rotation``, ``--lambdas`` and ``--neighbourhood``. Every flag defaults to None (= not given)."""
    parser.add_argument("--config", default=None, help="a JSON settings file (see configs/); flags given override it")
    parser.add_argument("--T", type=int, default=None, help=f"points per branch after resampling (default {DEFAULT_T})")
    parser.add_argument("--max-layers", type=int, default=None, help="keep at most this many branch layers")
    parser.add_argument("--min-branch-length", type=float, default=None,
                        help="drop SWC side branches shorter than this")
    parser.add_argument("--repair", action="store_true", default=None,
                        help="mend SWC cycles / parts cut off from the root (warns)")
    parser.add_argument("--hierarchy", choices=("straightest", "heaviest", "longest"), default=None,
                        help="which child continues a branch at an SWC branch point (default straightest: stable as "
                             "plants grow; longest = the paper's longest-path rule)")
    if registration:
        parser.add_argument("--rotation", choices=ROTATIONS, default=None,
                            help="global rotation to optimise (default none: the scans share a frame)")
        parser.add_argument("--lambdas", type=float, nargs=3, default=None, metavar=("LM", "LS", "LP"),
                            help="metric weights of main branch, subtrees, bifurcation parameters (default 1 1 1)")
        parser.add_argument("--neighbourhood", type=int, default=None,
                            help="largest DP slope (default 4; 6 for strongly non-uniform warps)")


def config_from_args(args: argparse.Namespace) -> Config:
    """The :class:`Config` of ``--config`` (or the defaults) with the flags given on the command line on top."""
    config = load_config(args.config) if getattr(args, "config", None) else Config()
    names = [f.name for f in dataclasses.fields(Config)]
    given = {name: getattr(args, name) for name in names if getattr(args, name, None) is not None}
    try:
        return dataclasses.replace(config, **given)
    except TreeError as e:
        raise TreeError(f"command line: {e}") from None
