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

from .settings import (
    CROSS_LP,
    CROSS_ORDER_TOL,
    CROSS_POSITIONS,
    DEFAULT_HIERARCHY,
    DEFAULT_MAX_SLOTS,
    DEFAULT_MODEL,
    DEFAULT_NT,
    DEFAULT_POSITIONS,
    DEFAULT_ROOT,
    DEFAULT_T,
    HIERARCHIES,
    MODELS,
    POSITIONS,
    ROOTS,
    ROTATIONS,
    CrossSettings,
    ModelSettings,
    OrganSettings,
    RegistrationSettings,
    check_at_least,
    check_choice,
    check_lambdas,
    check_optional_number,
    check_share,
    setting_error,
    settings_from_dict,
)

# the settings that decide how files become trees (the fields of io.LoadOptions that a config sets)
LOAD_SETTINGS = ("T", "max_layers", "min_branch_length", "repair", "hierarchy", "joint_hierarchy", "root")


@dataclass
class Config:
    """Loading, registration and model settings (docs/method.md §2, §3, §5), one JSON key per field.

    :meth:`registration_settings`, :meth:`cross_settings`, :meth:`model_settings` (the paper's model) and
    :meth:`organ_settings` (the organ model) give the typed settings the functions take; ``model`` chooses which
    model ``torch4dtree fit`` fits (:data:`~torch4dtree.settings.MODELS`).

    Example:
        >>> cfg = Config(rotation="vertical", cross_lp=None, n_t=8)
        >>> cfg.cross_settings().lp is None, cfg.model_settings().n_t
        (True, 8)
        >>> Config(model="organs", organ_bandwidth=1.0).organ_settings().bandwidth
        1.0
        >>> Config(**cfg.to_dict()) == cfg
        True
        >>> Config(cross_positions="fraction")  # doctest: +ELLIPSIS
        Traceback (most recent call last):
        ...
        torch4dtree.trees.structures.TreeError: cross_positions must be one of (...), got 'fraction'
    """

    T: int = DEFAULT_T
    max_layers: int | None = None
    min_branch_length: float = 0.0
    repair: bool = False
    hierarchy: str = DEFAULT_HIERARCHY  # skeleton -> branches rule (torch4dtree.trees.skeleton)
    joint_hierarchy: bool = True  # SWC sequences: main branches that agree over time (torch4dtree.trees.growth)
    root: str = DEFAULT_ROOT  # where an SWC skeleton is rooted (torch4dtree.io.rooting)
    rotation: str = "none"
    lambdas: tuple[float, float, float] = (1.0, 1.0, 1.0)  # (lm, ls, lp)
    neighbourhood: int = 4  # DP slopes up to 4: fastest and most cycle-consistent on Pheno4D at T = 64
    # how two trees' children are compared in pair registrations (torch4dtree register); the Karcher mean and the
    # tree space register with "warped" (their layout's metric), cross-sequence registrations with cross_positions
    positions: str = DEFAULT_POSITIONS
    # cross-sequence registrations (register4d, the model's population): children's positions, relative lp
    # (null: lambdas[2]) and order tolerance (null: children matched in any order); within a sequence,
    # register_sequence keeps its own (settings.CrossSettings)
    cross_positions: str = CROSS_POSITIONS
    cross_lp: float | None = CROSS_LP
    cross_order_tol: float | None = CROSS_ORDER_TOL
    # the generative model (docs/method.md §5): "paper" (torch4dtree.model.FourDTreeModel) or "organs"
    # (torch4dtree.model.OrganModel)
    model: str = DEFAULT_MODEL
    # the paper's model
    n_t: int = DEFAULT_NT  # common time samples of the trajectories
    tree_components: int | None = None  # tree-PCA components (None: the share tree_variance)
    tree_variance: float = 0.99
    modes: int | None = None  # trajectory-PCA modes (None: the share mode_variance)
    mode_variance: float = 0.95
    c: float = 3.0  # sampler truncation (both models): coefficients / latent noise in [-c, c]
    medoid_candidates: int = 3  # candidates for the population's reference 4D tree
    max_slots: int | None = DEFAULT_MAX_SLOTS  # the population layout's slot bound (null: unbounded)
    mean_iters: int = 10  # rounds of the 4D Karcher mean
    # the organ model (settings.OrganSettings): latent kernel width (sd), chance an organ keeps its donor plant,
    # log-length noise
    organ_bandwidth: float = OrganSettings.bandwidth
    organ_persistence: float = OrganSettings.persistence
    organ_jitter: float = OrganSettings.jitter
    render_size: int = 256  # pixels per cell of the figures and videos
    notes: str = field(default="", compare=False)

    def __post_init__(self) -> None:
        check_at_least("T", self.T, 2)
        check_choice("hierarchy", self.hierarchy, HIERARCHIES)
        check_choice("root", self.root, ROOTS)
        check_choice("rotation", self.rotation, ROTATIONS)
        self.lambdas = check_lambdas(self.lambdas)
        check_choice("positions", self.positions, POSITIONS)
        check_choice("cross_positions", self.cross_positions, POSITIONS)
        self.cross_lp = check_optional_number("cross_lp", self.cross_lp)
        self.cross_order_tol = check_optional_number("cross_order_tol", self.cross_order_tol)
        check_at_least("neighbourhood", self.neighbourhood, 1)
        check_at_least("n_t", self.n_t, 2)
        for name in ("medoid_candidates", "mean_iters", "render_size"):
            check_at_least(name, getattr(self, name), 1)
        for name in ("tree_components", "modes"):
            if getattr(self, name) is not None:
                check_at_least(name, getattr(self, name), 1)
        for name in ("tree_variance", "mode_variance"):
            check_share(name, getattr(self, name))
        check_choice("model", self.model, MODELS)
        self.model_settings()  # the rest (c...) as the model checks it
        for name in ("bandwidth", "persistence", "jitter"):
            try:
                OrganSettings(**{name: getattr(self, f"organ_{name}")})
            except ValueError as e:  # TreeError is a ValueError
                raise setting_error(f"organ_{name}: {e}") from None

    def registration_settings(self) -> RegistrationSettings:
        """How the tree registrations search (the DP's ``neighbourhood``; the rest default)."""
        return RegistrationSettings(neighbourhood=self.neighbourhood)

    def cross_settings(self) -> CrossSettings:
        """The cross-sequence registration settings (:func:`~torch4dtree.temporal.register4d`'s ``cross``)."""
        return CrossSettings(positions=self.cross_positions, lp=self.cross_lp, order_tol=self.cross_order_tol)

    def model_settings(self) -> ModelSettings:
        """The :class:`~torch4dtree.model.FourDTreeModel` settings these give."""
        return ModelSettings(lambdas=self.lambdas, rotation=self.rotation, n_t=self.n_t,
                             tree_components=self.tree_components, tree_variance=self.tree_variance,
                             modes=self.modes, mode_variance=self.mode_variance, c=self.c,
                             medoid_candidates=self.medoid_candidates, mean_iters=self.mean_iters,
                             registration=self.registration_settings(), cross=self.cross_settings(),
                             max_slots=self.max_slots)

    def organ_settings(self) -> OrganSettings:
        """The :class:`~torch4dtree.model.OrganModel` settings these give (``c``, the ``organ_*`` keys, the
        registration search of :meth:`registration_settings`; generated plants as many frames as the training
        plants' median)."""
        return OrganSettings(n_ages=None, bandwidth=self.organ_bandwidth, persistence=self.organ_persistence,
                             jitter=self.organ_jitter, c=self.c, registration=self.registration_settings())

    def load_options(self):  # noqa: ANN201 - io.LoadOptions (io imports structures; keep this module light)
        """The :class:`~torch4dtree.io.LoadOptions` with every setting the two share taken from here."""
        from .io import LoadOptions

        return LoadOptions(**{name: getattr(self, name) for name in LOAD_SETTINGS})

    def to_dict(self) -> dict:
        """The settings as a JSON-ready dict (the keys a config file uses)."""
        out = dataclasses.asdict(self)
        out["lambdas"] = list(self.lambdas)
        return out


def load_config(path: str | Path) -> Config:
    """Read a JSON config; keys not listed in :class:`Config` are rejected with their name.

    Example:
        >>> from pathlib import Path
        >>> import torch4dtree
        >>> load_config(Path(torch4dtree.__file__).parents[1] / "configs" / "tomato.json").rotation
        'none'
    """
    path = Path(path)
    try:
        raw = json.loads(path.read_text())
    except (OSError, ValueError) as e:
        raise setting_error(f"{path}: cannot read the config ({e})") from None
    if not isinstance(raw, dict):
        raise setting_error(f"{path}: a config is a JSON object of settings")
    try:
        return settings_from_dict(Config, raw, "the config")
    except ValueError as e:  # TreeError is a ValueError
        raise setting_error(f"{path}: {e}") from None
