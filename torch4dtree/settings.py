"""The package's choices, defaults and typed settings in one torch-free module.

Every module that validates a choice (rotation, children's positions, hierarchy rule) or needs a default imports it
from here, so a default changes in one place, and the command line can build its help without importing torch.
Each stage of the pipeline takes its settings as one frozen dataclass, validated when built:

* :class:`RegistrationSettings`: how a tree registration searches (DP lattice, rotation starts, iterations);
* :class:`CrossSettings`: how two plants' trees are matched (children's positions, ``lp``, order of children);
* :class:`TemporalSettings`: the time-warp DP of two trajectories;
* :class:`ModelSettings`: the paper's generative model, holding the three above;
* :class:`OrganSettings`: the organ-by-organ generative model (:data:`MODELS` names the two).

They travel as plain dicts (``to_dict`` / ``from_dict``) in checkpoints and JSON. The measured reasons for each
default are in ``docs/method.md`` and ``docs/experiments.md``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

__all__ = [
    "CROSS_LP", "CROSS_ORDER_TOL", "CROSS_POSITIONS", "DEFAULT_NT", "DEFAULT_POSITIONS", "DEFAULT_T",
    "DEFAULT_HIERARCHY", "DEFAULT_ROOT", "ROOTS", "SEQUENCE_POSITIONS",
    "DEFAULT_MODEL", "FALLBACK_ROTATION", "HIERARCHIES", "MODELS", "ORDER_TOL", "POSITIONS", "ROTATIONS",
    "TEMPORAL_BACKENDS", "TEMPORAL_NEIGHBOURHOOD", "TEMPORAL_REFINE", "TIME_WEIGHT", "WITHIN_LAMBDAS", "CrossSettings",
    "ModelSettings", "OrganSettings", "RegistrationSettings", "TemporalSettings", "check_at_least", "check_choice",
    "check_lambdas", "check_optional_number", "check_share", "setting_error", "settings_from_dict",
]

# global rotation searched by a registration: data in one frame, about the up axis, or any (docs/method.md §3)
ROTATIONS = ("none", "vertical", "so3")
# how two trees' matched children are compared: the parent's warp, arc length, node rank on the main branch or on every
# branch (docs/method.md §3)
POSITIONS = ("warped", "arclength", "rank",
             "closest",  # the closest of node rank, arc length and share of the parent (one plant's frames)
             "nodes")
# skeleton -> branch hierarchy: which child continues a branch at a branch point (docs/method.md §2)
HIERARCHIES = ("straightest", "heaviest", "longest", "continuation")
# the default rule; "continuation" (straightness weighed with what each child carries) is an option whose gain on
# woody trees is not yet clear across plant sets (docs/experiments.md)
DEFAULT_HIERARCHY = "straightest"
# where an SWC skeleton is rooted: "auto" a plant's stem base where the file roots it at a leaf tip hanging below
# it, "base" the stem base always, "file" the file's own root (docs/method.md §6)
ROOTS = ("auto", "base", "file")
DEFAULT_ROOT = "auto"

DEFAULT_T = 64  # points per branch
DEFAULT_POSITIONS = "rank"  # pair registrations
# one plant's frames (register_sequence): an organ keeps its node rank, its arc length or (a stem that grew little) its
# share of the stem on the main branch, its arc length or share below it (docs/method.md §3): elongating internodes,
# axes that grow at their tip and axes that elongate throughout all keep identities
SEQUENCE_POSITIONS = "closest"
DEFAULT_NT = 32  # common time samples of a trajectory
# the population's union layout keeps at most this many slots (the ones carrying the most of the training frames'
# norm; docs/scaling.md): bounds the fit's features and registrations in the number of plants
DEFAULT_MAX_SLOTS = 512
ORDER_TOL = 0.02  # siblings closer than this share of their parent may match in any order
# within-sequence registrations (frame j onto j + 1): lp 9 relative favours identities between consecutive frames
WITHIN_LAMBDAS = (1.0, 1.0, 9.0)
# cross-sequence registrations (two plants): node ranks on every axis, relative lp 100, children kept in order.
# Plants of a kind carry their organs in one order up each axis (leaf k below leaf k + 1), and node k of one plant is
# node k of another; lp is used by the registration only, the 4D distance keeps the space's metric
CROSS_POSITIONS = "nodes"
CROSS_LP: float | None = 100.0
CROSS_ORDER_TOL: float | None = ORDER_TOL
# register4d's wider rotation search, run only where the asked rotation finds no correspondence better than the
# index order (it costs about 10x rotation="none")
FALLBACK_ROTATION: str | None = "vertical"
# register4d's weight on a time coordinate appended to both trajectories in a second warp search: a penalty on warping
# that scales with the trajectories and with how far they are from time warps of each other (two plants never trace
# the same curve, and the plain energy's minimum fits their differences with steep jumps of the warp). The 4D mean and
# PCA use the plain distance (weight 0, register_trajectories' default).
TIME_WEIGHT = 1.0
# the time-warp DP: slopes up to 4, then 16 Gauss-Newton steps off the lattice (docs/method.md §5)
TEMPORAL_NEIGHBOURHOOD = 4
TEMPORAL_REFINE = 16
TEMPORAL_BACKENDS = ("auto", "numba", "torch")
# the generative models (docs/method.md §5): organ by organ (torch4dtree.model.OrganModel, OrganSettings) or the
# paper's 4D mean and modes (torch4dtree.model.FourDTreeModel, ModelSettings)
MODELS = ("organs", "paper")
# samples beside held-out plants: morphometric 1-NNA 0.52-0.68 against 0.92-1.00 (docs/experiments.md, E)
DEFAULT_MODEL = "organs"


def setting_error(message: str) -> ValueError:
    """A :class:`~torch4dtree.trees.TreeError` for a bad setting (the tree module imported only when there is an
    error to raise, so this module stays torch-free)."""
    from .trees.structures import TreeError

    return TreeError(message)


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
        raise setting_error(f"{name} must be one of {tuple(choices)}, got {value!r}")


def _is_number(value: object) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def check_at_least(name: str, value: object, low: int) -> int:
    """``value`` as an ``int`` if it is an integer ``>= low``; else a TreeError naming the setting.

    Example:
        >>> check_at_least("n_t", 0, 2)
        Traceback (most recent call last):
        ...
        torch4dtree.trees.structures.TreeError: n_t must be an integer >= 2, got 0
    """
    if not (_is_number(value) and math.isfinite(value) and float(value) == int(value)  # type: ignore[arg-type]
            and value >= low):  # type: ignore[operator]
        raise setting_error(f"{name} must be an integer >= {low}, got {value!r}")
    return int(value)  # type: ignore[call-overload]


def check_optional_number(name: str, value: object) -> float | None:
    """``None``, or ``value`` as a ``float`` if it is a finite number ``>= 0``; else a TreeError naming the setting."""
    if value is None:
        return None
    if not (_is_number(value) and 0 <= value < math.inf):  # type: ignore[operator]
        raise setting_error(f"{name} must be null or a finite number >= 0, got {value!r}")
    return float(value)  # type: ignore[arg-type]


def check_share(name: str, value: object) -> float:
    """``value`` as a ``float`` if it is in ``(0, 1]``; else a TreeError naming the setting."""
    if not (_is_number(value) and 0 < value <= 1):  # type: ignore[operator]
        raise setting_error(f"{name} must be in (0, 1], got {value!r}")
    return float(value)  # type: ignore[arg-type]


def check_lambdas(lambdas: Sequence[float], name: str = "lambdas") -> tuple[float, float, float]:
    """``(lm, ls, lp)`` as floats with ``lm > 0``, ``ls > 0``, ``lp >= 0`` (docs/method.md §3); else a TreeError.

    Example:
        >>> check_lambdas([1, 1, 9])
        (1.0, 1.0, 9.0)
    """
    try:
        lam = tuple(float(x) for x in lambdas)
    except (TypeError, ValueError):
        raise setting_error(f"{name} must be (lm > 0, ls > 0, lp >= 0), got {lambdas!r}") from None
    if len(lam) != 3 or not all(math.isfinite(x) and x >= 0 for x in lam) or lam[0] <= 0 or lam[1] <= 0:
        raise setting_error(f"{name} must be (lm > 0, ls > 0, lp >= 0), got {tuple(lambdas)}")
    return lam  # type: ignore[return-value]


def _optional_int(name: str, value: object, low: int) -> int | None:
    return None if value is None else check_at_least(name, value, low)


def _positive(name: str, value: object) -> float:
    """``value`` as a ``float`` if it is a finite number ``> 0``; else a TreeError naming the setting."""
    if not (_is_number(value) and 0 < value < math.inf):  # type: ignore[operator]
        raise setting_error(f"{name} must be a positive number, got {value!r}")
    return float(value)  # type: ignore[arg-type]


def settings_from_dict(cls: type, data: Mapping[str, Any], what: str) -> Any:
    """``cls(**data)`` for a settings dataclass, unknown keys rejected by name and a value of the wrong kind as a
    TreeError (``what`` names the settings in the messages).

    Example:
        >>> settings_from_dict(CrossSettings, {"lp": 6}, "cross").lp
        6.0
        >>> settings_from_dict(CrossSettings, {"lpp": 6}, "cross")  # doctest: +ELLIPSIS
        Traceback (most recent call last):
        ...
        torch4dtree.trees.structures.TreeError: unknown setting(s) ['lpp'] of cross; known: [...]
    """
    if not isinstance(data, Mapping):
        raise setting_error(f"{what} must be a mapping of settings, got {type(data).__name__}")
    known = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - known)
    if unknown:
        raise setting_error(f"unknown setting(s) {unknown} of {what}; known: {sorted(known)}")
    try:
        return cls(**data)
    except TypeError as e:  # a value of the wrong kind (the checks raise TreeError, a ValueError)
        raise setting_error(f"{what}: {e}") from None


def _plain(value: object) -> object:
    """Tuples as lists, recursively (JSON and ``torch.load(weights_only=True)`` friendly)."""
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (tuple, list)):
        return [_plain(v) for v in value]
    return value


class _PlainDict:
    """``to_dict`` / ``from_dict`` of a settings dataclass (``_what`` names it in errors)."""

    _what = "settings"

    def to_dict(self) -> dict[str, Any]:
        """The settings as a plain dict (nested dicts for nested settings, lists for tuples)."""
        return _plain(dataclasses.asdict(self))  # type: ignore[call-overload, return-value]

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Any:
        """Settings from a dict of some of the fields (the others default); unknown keys are errors."""
        return settings_from_dict(cls, data, cls._what)


@dataclass(frozen=True)
class RegistrationSettings(_PlainDict):
    """How a tree registration searches (:func:`~torch4dtree.trees.register_to_reference`'s search settings).

    Every stage (within-sequence, cross-sequence, Karcher mean) searches with these; what it matches (weights,
    rotation, children's positions and order) is the stage's own.

    Attributes:
        up: the vertical axis of ``rotation="vertical"`` (default z).
        n_starts: starting rotations about the vertical, besides the identity.
        max_iters, tol: rounds of (warps + assignments, rotation) and their relative stopping tolerance.
        neighbourhood, band, coarse, refine: the branch DP's lattice slopes, band, coarse grid and refinement
            steps (:func:`~torch4dtree.curves.dp_warp`).
        prune: skip subtree pairs that provably cannot match (exact).

    Example:
        >>> RegistrationSettings(neighbourhood=6).neighbourhood
        6
        >>> RegistrationSettings(n_starts=-1)
        Traceback (most recent call last):
        ...
        torch4dtree.trees.structures.TreeError: n_starts must be an integer >= 0, got -1
    """

    up: tuple[float, float, float] | None = None
    n_starts: int = 12
    max_iters: int = 10
    tol: float = 1e-3
    neighbourhood: int = 4
    band: int | None = None
    coarse: int | None = 32
    refine: int = 0
    prune: bool = True

    def __post_init__(self) -> None:
        if self.up is not None:
            up = tuple(float(x) for x in self.up)
            if len(up) != 3 or not all(math.isfinite(x) for x in up) or not any(up):
                raise setting_error(f"up must be null or a non-zero 3-vector, got {self.up!r}")
            object.__setattr__(self, "up", up)
        object.__setattr__(self, "n_starts", check_at_least("n_starts", self.n_starts, 0))
        object.__setattr__(self, "max_iters", check_at_least("max_iters", self.max_iters, 1))
        tol = check_optional_number("tol", self.tol)
        if tol is None:
            raise setting_error("tol must be a finite number >= 0, got None")
        object.__setattr__(self, "tol", tol)
        object.__setattr__(self, "neighbourhood", check_at_least("neighbourhood", self.neighbourhood, 1))
        object.__setattr__(self, "band", _optional_int("band", self.band, 1))
        object.__setattr__(self, "coarse", _optional_int("coarse", self.coarse, 2))
        object.__setattr__(self, "refine", check_at_least("refine", self.refine, 0))
        if not isinstance(self.prune, bool):
            raise setting_error(f"prune must be true or false, got {self.prune!r}")

    def register(self, trees: Any, reference: Any, lambdas: Sequence[float], rotation: str, *, positions: str,
                 order_tol: float | None, lp_relative: bool, symmetric: bool) -> list[Any]:
        """:func:`~torch4dtree.trees.register_to_reference` of ``trees`` onto ``reference`` with these settings and
        the stage's own choices; one :class:`~torch4dtree.trees.TreeRegistration` per moving tree."""
        from .trees.registration import register_to_reference

        return register_to_reference(
            trees, reference, lambdas, rotation, up=self.up, n_starts=self.n_starts, max_iters=self.max_iters,
            tol=self.tol, neighbourhood=self.neighbourhood, band=self.band, coarse=self.coarse, refine=self.refine,
            prune=self.prune, lp_relative=lp_relative, positions=positions, order_tol=order_tol,
            symmetric=symmetric)

    _what = "registration"


@dataclass(frozen=True)
class CrossSettings(_PlainDict):
    """How two plants' trees are registered onto each other (register4d's spatial stage, the population space).

    Attributes:
        positions: how matched children's places are compared (:data:`POSITIONS`).
        lp: the registration's relative ``lp`` (``None``: the space's ``lambdas[2]``); the 4D distance keeps the
            space's metric.
        order_tol: a node's children matched in their order along the parent, siblings closer than this share of
            the parent in any order; ``None``: any order (docs/method.md §3).
        fallback_rotation: where the asked rotation finds no correspondence better than the index order, the
            registration is searched again with this rotation (``None``: never; docs/method.md §5).

    Example:
        >>> CrossSettings(lp=None).lp is None
        True
        >>> CrossSettings(positions="fraction")  # doctest: +ELLIPSIS
        Traceback (most recent call last):
        ...
        torch4dtree.trees.structures.TreeError: positions must be one of ('warped', ..., 'nodes'), got 'fraction'
    """

    positions: str = CROSS_POSITIONS
    lp: float | None = CROSS_LP
    order_tol: float | None = CROSS_ORDER_TOL
    fallback_rotation: str | None = FALLBACK_ROTATION

    def __post_init__(self) -> None:
        check_choice("positions", self.positions, POSITIONS)
        object.__setattr__(self, "lp", check_optional_number("cross_lp", self.lp))
        object.__setattr__(self, "order_tol", check_optional_number("cross_order_tol", self.order_tol))
        if self.fallback_rotation is not None:
            check_choice("fallback_rotation", self.fallback_rotation, ROTATIONS)

    _what = "cross"


@dataclass(frozen=True)
class TemporalSettings(_PlainDict):
    """The time-warp DP of two trajectories (:func:`~torch4dtree.temporal.register_trajectories`).

    Attributes:
        neighbourhood, refine, band, coarse, backend: lattice slopes, Gauss-Newton steps off the lattice, band and
            coarse grid of the DP (``None``: whole lattice), and its backend (:data:`TEMPORAL_BACKENDS`).

    Example:
        >>> TemporalSettings().refine
        16
    """

    neighbourhood: int = TEMPORAL_NEIGHBOURHOOD
    refine: int = TEMPORAL_REFINE
    band: int | None = None
    coarse: int | None = None
    backend: str = "auto"

    def __post_init__(self) -> None:
        object.__setattr__(self, "neighbourhood", check_at_least("neighbourhood", self.neighbourhood, 1))
        object.__setattr__(self, "refine", check_at_least("refine", self.refine, 0))
        object.__setattr__(self, "band", _optional_int("band", self.band, 1))
        object.__setattr__(self, "coarse", _optional_int("coarse", self.coarse, 2))
        check_choice("backend", self.backend, TEMPORAL_BACKENDS)

    def register(self, alpha_ref: Any, alpha_mov: Any, time_weight: float = 0.0) -> Any:
        """:func:`~torch4dtree.temporal.register_trajectories` with these settings."""
        from .temporal.registration import register_trajectories

        return register_trajectories(alpha_ref, alpha_mov, neighbourhood=self.neighbourhood, refine=self.refine,
                                     band=self.band, coarse=self.coarse, backend=self.backend,
                                     time_weight=time_weight)

    _what = "temporal"


# the flat keys of a model's settings as checkpoints wrote them before the cross settings were grouped
_FLAT_CROSS = {"positions": "positions", "cross_lp": "lp", "cross_order_tol": "order_tol"}


@dataclass(frozen=True)
class ModelSettings(_PlainDict):
    """The generative model's settings (:class:`~torch4dtree.model.FourDTreeModel`, docs/method.md §5).

    Attributes:
        lambdas: ``(lm, ls, lp)`` of the tree space; ``lp`` relative to the plants' size.
        rotation: the cross-sequence registrations' global rotation (:data:`ROTATIONS`).
        n_t: common time samples of the trajectories.
        tree_components, tree_variance: the tree PCA's components (``None``: the share ``tree_variance``).
        modes, mode_variance: the trajectory PCA's modes (``None``: the share ``mode_variance``).
        c: the sampler's truncation bound (coefficients in ``[-c, c]``).
        medoid_candidates: candidates for the population's reference 4D tree.
        mean_iters: rounds of the 4D Karcher mean.
        registration, cross, temporal: the stages' settings.
        max_slots: the population layout's slot bound (``None``: unbounded).

    Example:
        >>> s = ModelSettings(n_t=8, cross=CrossSettings(lp=None))
        >>> ModelSettings.from_dict(s.to_dict()) == s
        True
        >>> ModelSettings(c=0)
        Traceback (most recent call last):
        ...
        torch4dtree.trees.structures.TreeError: c must be a positive number, got 0
    """

    lambdas: tuple[float, float, float] = (1.0, 1.0, 1.0)
    rotation: str = "none"
    n_t: int = DEFAULT_NT
    tree_components: int | None = None
    tree_variance: float = 0.99
    modes: int | None = None
    mode_variance: float = 0.95
    c: float = 3.0
    medoid_candidates: int = 3
    mean_iters: int = 10
    registration: RegistrationSettings = field(default_factory=RegistrationSettings)
    cross: CrossSettings = field(default_factory=CrossSettings)
    temporal: TemporalSettings = field(default_factory=TemporalSettings)
    max_slots: int | None = DEFAULT_MAX_SLOTS

    def __post_init__(self) -> None:
        object.__setattr__(self, "max_slots", _optional_int("max_slots", self.max_slots, 1))
        object.__setattr__(self, "lambdas", check_lambdas(self.lambdas))
        check_choice("rotation", self.rotation, ROTATIONS)
        object.__setattr__(self, "n_t", check_at_least("n_t", self.n_t, 2))
        object.__setattr__(self, "tree_components", _optional_int("tree_components", self.tree_components, 1))
        object.__setattr__(self, "modes", _optional_int("modes", self.modes, 1))
        object.__setattr__(self, "tree_variance", check_share("tree_variance", self.tree_variance))
        object.__setattr__(self, "mode_variance", check_share("mode_variance", self.mode_variance))
        object.__setattr__(self, "c", _positive("c", self.c))
        object.__setattr__(self, "medoid_candidates", check_at_least("medoid_candidates", self.medoid_candidates, 1))
        object.__setattr__(self, "mean_iters", check_at_least("mean_iters", self.mean_iters, 1))
        for name, cls in (("registration", RegistrationSettings), ("cross", CrossSettings),
                          ("temporal", TemporalSettings)):
            if not isinstance(getattr(self, name), cls):
                raise setting_error(f"{name} must be a {cls.__name__}, got {type(getattr(self, name)).__name__}")

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> ModelSettings:
        """Settings from :meth:`to_dict`'s dict, or from the flat form older checkpoints saved (``positions``,
        ``cross_lp``, ``cross_order_tol`` at the top level); missing keys default, unknown keys are errors."""
        if not isinstance(data, Mapping):
            raise setting_error(f"model settings must be a mapping, got {type(data).__name__}")
        data = dict(data)
        flat_keys = sorted(k for k in data if k in _FLAT_CROSS)
        flat = {_FLAT_CROSS[k]: data.pop(k) for k in flat_keys}
        cross = data.pop("cross", None)
        if flat and cross is not None:
            raise setting_error(f"model settings give both 'cross' and {flat_keys}")
        out = {"cross": CrossSettings.from_dict(cross if cross is not None else flat)}
        for name, stage in (("registration", RegistrationSettings), ("temporal", TemporalSettings)):
            value = data.pop(name, None)
            if value is not None:
                out[name] = stage.from_dict(value)
        return settings_from_dict(cls, {**data, **out}, "model")


@dataclass(frozen=True)
class OrganSettings(_PlainDict):
    """The organ-by-organ generative model's settings (:class:`~torch4dtree.model.OrganModel`, docs/method.md §5).

    Attributes:
        n_ages: frames of a generated plant (normalised ages ``linspace(0, 1, n_ages)``); ``None``: the training
            plants' median number of frames.
        bandwidth: the kernel's least width over the plant latent, in standard deviations (small: samples follow single
            training plants; large: organs drawn from the whole population regardless of the plant's vigour); the
            model widens it on small populations until a sample draws on several plants
            (:meth:`~torch4dtree.model.OrganModel.donor_bandwidth`).
        persistence: the chance that an organ copies the same training plant as the organ it follows (its previous
            sibling, or its parent for a first child); otherwise it switches to a plant drawn near the latent. 1
            copies whole plants, 0 draws every organ afresh.
        jitter: standard deviation of the log-length noise added to a drawn organ (0.1: about 10 %).
        c: truncation of the latent's standard normal noise.
        registration: how each plant's within-sequence registration searches (organ identities over time;
            :func:`~torch4dtree.temporal.register_sequence`'s ``registration``).

    Example:
        >>> s = OrganSettings(bandwidth=1.0, registration=RegistrationSettings(neighbourhood=6))
        >>> OrganSettings.from_dict(s.to_dict()) == s
        True
        >>> OrganSettings(persistence=1.5)
        Traceback (most recent call last):
        ...
        torch4dtree.trees.structures.TreeError: persistence must be in [0, 1], got 1.5
    """

    n_ages: int | None = None
    bandwidth: float = 0.6
    persistence: float = 0.7
    jitter: float = 0.1
    c: float = 3.0
    registration: RegistrationSettings = field(default_factory=RegistrationSettings)

    def __post_init__(self) -> None:
        object.__setattr__(self, "n_ages", _optional_int("n_ages", self.n_ages, 2))
        object.__setattr__(self, "bandwidth", _positive("bandwidth", self.bandwidth))
        object.__setattr__(self, "c", _positive("c", self.c))
        if not (_is_number(self.persistence) and 0 <= self.persistence <= 1):
            raise setting_error(f"persistence must be in [0, 1], got {self.persistence!r}")
        object.__setattr__(self, "persistence", float(self.persistence))
        jitter = check_optional_number("jitter", self.jitter)
        if jitter is None:
            raise setting_error("jitter must be a finite number >= 0, got None")
        object.__setattr__(self, "jitter", jitter)
        if not isinstance(self.registration, RegistrationSettings):
            raise setting_error(f"registration must be a RegistrationSettings, got "
                                f"{type(self.registration).__name__}")

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> OrganSettings:
        """Settings from :meth:`to_dict`'s dict (``registration`` a nested dict); missing keys default, unknown keys
        are errors."""
        if not isinstance(data, Mapping):
            raise setting_error(f"organ settings must be a mapping, got {type(data).__name__}")
        data = dict(data)
        registration = data.pop("registration", None)
        if registration is not None:
            data["registration"] = RegistrationSettings.from_dict(registration)
        return settings_from_dict(cls, data, "organs")

    _what = "organs"
