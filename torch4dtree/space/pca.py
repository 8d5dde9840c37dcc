"""Tree PCA (docs/method.md §4, paper §4.1): principal components of registered trees' weighted SRVFT features.

In a common slot layout :meth:`AlignedTrees.features` is a flat vector whose Euclidean norm of differences
is the tree metric, so PCA is an SVD of the centred features. Coefficients are projections on orthonormal
components: Euclidean distances between coefficient vectors are tree-metric distances within the principal
subspace (exactly the feature distances with all components kept). Decoding maps coefficients back to
features, then to trees in the fitted layout.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from typing import Any, NamedTuple

import torch
from torch import Tensor

from ..curves.srvf import srvf_sq_norm
from ..settings import check_lambdas
from ..trees.aligned import AlignedTrees, Lambdas, SlotRows, rows_to_trees, slot_weights
from ..trees.structures import Trees
from .fitted import FittedModule, NotFittedError

__all__ = ["TreePCA", "feature_blocks", "gram_axes"]

# decode drops branches shorter than this fraction of the mean's main branch (see TreePCA.decode)
DECODE_MIN_FRACTION = 0.01
# decode measures its trees' slot lengths on this many feature values at a time (float64: 32 MB)
DECODE_CHUNK_VALUES = 1 << 22
# the Gram path (gram_axes) keeps components whose singular value is at least this share of the largest: its
# components then agree with the SVD's to about eps / GRAM_MIN_SHARE^2 (1e-10); a smaller kept one takes the SVD
GRAM_MIN_SHARE = 1e-3
# dense features from this size up (bytes) take the Gram path in TreePCA.fit; smaller fits keep the SVD of the dense
# features (results identical to the last bit there; their memory is small anyway)
GRAM_MIN_BYTES = 1 << 26
# feature columns per block of the Gram path (a few MB of float64 per tree): the dense (n, F) features are never
# built, only one block of them at a time
GRAM_BLOCK_COLUMNS = 1 << 16


def principal_axes(x: Tensor) -> tuple[Tensor, Tensor]:
    """Singular values ``(r,)`` and right singular vectors ``(r, F)`` of ``x (n, F)``, ``r = min(n, F)``.

    For ``n < F`` (a few trees or plants, many features) this is the SVD of the transpose: LAPACK factors the tall
    matrix several times faster than the wide one (114 x 20000 on this project's machine: 0.12 against 0.84 s).
    """
    if x.shape[0] < x.shape[1]:
        U, sing, _ = torch.linalg.svd(x.T, full_matrices=False)
        return sing, U.T
    _, sing, Vh = torch.linalg.svd(x, full_matrices=False)
    return sing, Vh


def feature_blocks(aligned: AlignedTrees, columns: int = GRAM_BLOCK_COLUMNS) -> Iterator[Tensor]:
    """Column blocks of ``aligned.features()`` (``(n, F_b)`` each, in order, about ``columns`` columns; the same
    values), computed one at a time: concatenated they are the features, without the ``(n, F)`` matrix at once."""
    n, S, M, d = aligned.q.shape
    w_q, w_s = aligned.weights()
    unit = (w_q / M).sqrt()
    per = max(columns // (M * d), 1)
    for a in range(0, S, per):
        b = min(a + per, S)
        yield (aligned.q[:, a:b] * unit[None, a:b, None, None]).reshape(n, (b - a) * M * d)
    yield aligned.s[:, 1:] * w_s[1:].sqrt()


def gram_axes(aligned: AlignedTrees, k_of: Callable[[Tensor], int]) -> tuple[Tensor, Tensor, Tensor, float] | None:
    """The PCA of ``aligned.features()`` through the trees' Gram matrix, block by block (:func:`feature_blocks`).

    ``k_of(var)`` picks the number of components from the variances ``(n,)`` (descending). Returns ``(mean (F,),
    var (n,), components (k, F), total variance)``, with unnormalised signs, or ``None`` where a kept singular value
    is below ``GRAM_MIN_SHARE`` of the largest (the caller then takes the SVD). Memory: the ``(n, n)`` Gram matrix,
    the ``(k, F)`` components and one block, instead of the dense features and the SVD's copies of them.
    Why: fitted on every frame of a population, the dense features and their SVD are the fit's largest arrays.
    """
    n = aligned.q.shape[0]
    with torch.no_grad():
        means = [blk.mean(0) for blk in feature_blocks(aligned)]
        gram = aligned.q.new_zeros(n, n)
        for blk, mu in zip(feature_blocks(aligned), means):
            xc = blk - mu
            gram += xc @ xc.T
        evals, evecs = torch.linalg.eigh(gram)
        evals, evecs = evals.flip(0).clamp_min(0.0), evecs.flip(1)
        total = float(gram.diagonal().sum()) / (n - 1)
        var = evals / (n - 1)
        k = k_of(var)
        sing = evals[:k].sqrt()
        if k > len(var) or not bool(sing[-1] >= GRAM_MIN_SHARE * sing[0]) or not bool(sing[0] > 0):
            return None
        left = evecs[:, :k] / sing  # (n, k): components = left^T Xc
        comps = gram.new_empty(k, sum(len(mu) for mu in means))
        at = 0
        for blk, mu in zip(feature_blocks(aligned), means):
            torch.matmul(left.T, blk - mu, out=comps[:, at:at + len(mu)])
            at += len(mu)
    return torch.cat(means), var, comps, total


def variance_components(var: Tensor, variance: float) -> int:
    """The smallest ``k`` whose leading variances ``var`` (descending) reach the share ``variance`` of their sum (a
    rounding margin so that an exact share counts as reached); 1 if they sum to 0."""
    total = float(var.sum())
    if not total > 0:
        return 1
    return min(int((var.cumsum(0) / total < variance - 1e-12).sum()) + 1, len(var))


def check_components(n_components: int | None, variance: float) -> tuple[int | None, float]:
    """Validate a PCA's ``k`` (None or a positive int) and variance share (in ``(0, 1]``)."""
    if n_components is not None and (isinstance(n_components, bool) or int(n_components) < 1):
        raise ValueError(f"n_components must be None or a positive int, got {n_components!r}")
    if not 0.0 < variance <= 1.0:
        raise ValueError(f"variance must be in (0, 1], got {variance}")
    return (None if n_components is None else int(n_components)), float(variance)


class _SlotTables(NamedTuple):
    """Per-slot constants of a fitted :class:`TreePCA` for :meth:`TreePCA.decode`, in SRVF units (features are
    ``q sqrt(w_q / M)``): slot ``j``'s SRVF is ``mean_q[j] + c @ comp_q[j]`` for coefficients ``c (k,)``."""

    mean_q: Tensor  # (S, M*d)
    comp_q: Tensor  # (S, k, M*d)
    mean_norm: Tensor  # (S,) |mean_q[j]|
    comp_norm: Tensor  # (S,) Frobenius norm of comp_q[j]
    w_s: Tensor  # (S,) metric weight of each slot's s


class TreePCA(FittedModule):
    """PCA in the tree space: ``k`` fixed (``n_components``) or the smallest ``k`` explaining ``variance``.

    Fitted buffers (``F = S*M*d + S - 1`` features; ``.to()`` moves and casts them):
    ``mean (F,)``, ``components (k, F)`` orthonormal rows (sign: largest entry positive),
    ``explained_variance (k,)`` (eigenvalues of the covariance with ``1/(n-1)``), ``explained_variance_ratio (k,)``,
    ``mean_root (d,)`` (the roots are not features: decoding starts there), and the layout
    ``slot_parent (S,)``, ``slot_depth (S,)``; ``lambdas``, ``M``, ``d`` travel in the extra state, so a loaded
    module decodes on its own.

    Example:
        >>> from torch4dtree.data import synthetic_plant
        >>> from torch4dtree.space import KarcherMean
        >>> trees = synthetic_plant("maize", 0, n_frames=4, T=8).sequence.frames
        >>> aligned = KarcherMean(max_iters=1, progress=False).fit_transform(trees).aligned
        >>> pca = TreePCA(n_components=2).fit(aligned)
        >>> pca.transform(aligned).shape, pca.decode(torch.zeros(1, 2, dtype=torch.float64)).num_trees
        (torch.Size([4, 2]), 1)
    """

    _fitted_buffers = ("mean", "components", "explained_variance", "explained_variance_ratio", "mean_root",
                       "slot_parent", "slot_depth")

    def __init__(self, n_components: int | None = None, variance: float = 0.99) -> None:
        super().__init__()
        self.n_components, self.variance = check_components(n_components, variance)
        self.lambdas: Lambdas = (1.0, 1.0, 1.0)
        self.M = 0
        self.d = 0
        self.n_samples_ = 0
        self.total_variance_ = 0.0
        for name in ("mean", "explained_variance", "explained_variance_ratio", "mean_root"):
            self.register_buffer(name, torch.zeros(0))
        self.register_buffer("components", torch.zeros(0, 0))
        self.register_buffer("slot_parent", torch.zeros(0, dtype=torch.long))
        self.register_buffer("slot_depth", torch.zeros(0, dtype=torch.long))

    # ------------------------------------------------------------------------ state
    def get_extra_state(self) -> dict[str, Any]:
        return {"version": 1, "n_components": self.n_components, "variance": self.variance,
                "lambdas": list(self.lambdas), "M": self.M, "d": self.d, "n_samples": self.n_samples_,
                "total_variance": self.total_variance_}

    def set_extra_state(self, state: dict[str, Any]) -> None:
        if not isinstance(state, dict) or state.get("version") != 1:
            raise ValueError("not a TreePCA state (missing or unknown version)")
        self.n_components, self.variance = state["n_components"], state["variance"]
        self.lambdas = check_lambdas(state["lambdas"])
        self.M, self.d, self.n_samples_ = state["M"], state["d"], state["n_samples"]
        self.total_variance_ = state["total_variance"]

    @property
    def is_fitted(self) -> bool:
        return self.components.shape[0] > 0

    @property
    def n_components_(self) -> int:
        """``k``, the number of fitted components."""
        return self.components.shape[0]

    @property
    def num_slots(self) -> int:
        return self.slot_parent.shape[0]

    def _check_fitted(self) -> None:
        if not self.is_fitted:
            raise NotFittedError("TreePCA is not fitted: call fit() or load_state_dict() first")

    def _check_layout(self, aligned: AlignedTrees) -> None:
        if not isinstance(aligned, AlignedTrees):
            raise TypeError(f"expected AlignedTrees, got {type(aligned).__name__}")
        _, S, M, d = aligned.q.shape
        if (S, M, d) != (self.num_slots, self.M, self.d) or aligned.lambdas != self.lambdas or not torch.equal(
                aligned.slot_parent.to(self.slot_parent.device), self.slot_parent):
            raise ValueError(f"trees in another layout: (S, M, d) = {(S, M, d)}, lambdas {aligned.lambdas}; the PCA "
                             f"was fitted on {(self.num_slots, self.M, self.d)}, lambdas {self.lambdas} (write the "
                             f"trees in the fitted layout, e.g. with KarcherMean.transform)")

    # ------------------------------------------------------------------------ fit
    def fit(self, aligned: AlignedTrees) -> TreePCA:
        """Fit on ``n >= 2`` trees in one layout (principal axes of the centred ``aligned.features()``). Returns
        ``self``.

        With dense features of at least ``GRAM_MIN_BYTES``, fewer trees than features and float64, through the trees'
        Gram matrix block by block (:func:`gram_axes`: memory of the ``(n, n)`` Gram matrix and the components, not of
        the dense features); otherwise, or where a kept component is too weak for the Gram matrix's precision, the SVD
        of the dense features. The two agree to rounding (the components to about 1e-10)."""
        if not isinstance(aligned, AlignedTrees):
            raise TypeError(f"expected AlignedTrees, got {type(aligned).__name__}")
        n, S, M, d = aligned.q.shape
        if n < 2:
            raise ValueError(f"PCA needs at least 2 trees, got {n}")
        F = S * M * d + S - 1
        big = n * F * aligned.q.element_size() >= GRAM_MIN_BYTES
        gram = gram_axes(aligned, self._k_of) if big and n < F and aligned.q.dtype == torch.float64 else None
        if gram is not None:
            mean, var, comps, total = gram
        else:
            X = aligned.features().detach()
            mean = X.mean(0)
            Xc = X - mean
            sing, Vh = principal_axes(Xc)
            del X
            var = sing.square() / (n - 1)
            total = float(Xc.square().sum()) / (n - 1)
            if not total > 0:
                raise ValueError("the trees do not vary (all features equal): no principal components")
            comps = Vh[: self._k_of(var)]
        ratio = var / total
        k = comps.shape[0]
        top = comps.abs().argmax(1, keepdim=True)
        comps = comps.mul_(torch.sign(comps.gather(1, top)))  # deterministic signs (in place: comps is ours)
        self.lambdas, self.M, self.d = aligned.lambdas, M, d
        self.n_samples_, self.total_variance_ = n, total
        self._set_fitted(mean=mean, components=comps, explained_variance=var[:k], explained_variance_ratio=ratio[:k],
                         mean_root=aligned.root.detach().mean(0), slot_parent=aligned.slot_parent,
                         slot_depth=aligned.slot_depth)
        return self

    def _k_of(self, var: Tensor) -> int:
        """Components to keep of the variances ``var`` (descending): ``n_components`` or the ``variance`` share."""
        if self.n_components is None:
            return variance_components(var, self.variance)
        if self.n_components > len(var):
            raise ValueError(f"n_components={self.n_components} > min(n_trees, n_features) = {len(var)}")
        return self.n_components

    def fit_transform(self, aligned: AlignedTrees) -> Tensor:
        """``fit(aligned)`` then ``transform(aligned)``: ``(n, k)``."""
        return self.fit(aligned).transform(aligned)

    # ------------------------------------------------------------------------ maps
    def transform(self, aligned: AlignedTrees) -> Tensor:
        """Coefficients ``(n, k)``: projections of the centred features on the orthonormal components."""
        self._check_fitted()
        self._check_layout(aligned)
        X = aligned.features().to(self.mean)
        return (X - self.mean) @ self.components.T

    def inverse_features(self, coeffs: Tensor) -> Tensor:
        """Features ``(..., F) = mean + coeffs @ components`` from ``coeffs (..., k)`` (differentiable)."""
        self._check_fitted()
        if coeffs.shape[-1] != self.n_components_:
            raise ValueError(f"coefficients must end with k={self.n_components_}, got shape {tuple(coeffs.shape)}")
        return self.mean + coeffs.to(self.mean.dtype) @ self.components

    def inverse_transform(self, coeffs: Tensor, root: Tensor | None = None) -> AlignedTrees:
        """Trees in the fitted layout from ``coeffs (..., k)``: leading dims are flattened to ``n = prod(...)`` trees.

        Differentiable in ``coeffs`` (``q``, ``s`` and ``features()`` of the result). ``root``: ``(n, d)`` or
        ``(d,)``, default the training trees' mean root. ``present`` marks slots with a nonzero SRVF.
        """
        f = self.inverse_features(coeffs).reshape(-1, self.mean.shape[0])
        n = f.shape[0]
        r = self.mean_root if root is None else root.to(self.mean)
        return AlignedTrees.from_features(f, self._template(), r.expand(n, self.d))

    def decode(self, coeffs: Tensor, min_length: float | None = None) -> Trees:
        """Decoded trees from ``coeffs (..., k)`` (flattened like :meth:`inverse_transform`).

        A slot is present where its decoded branch is longer than ``min_length`` (default
        ``DECODE_MIN_FRACTION`` of the mean's main-branch length) and its parent slot is present; children
        start on their parent's curve. The result is ``inverse_transform(coeffs).to_trees(min_length)``
        (:meth:`AlignedTrees.to_trees`), computed without the SRVFs of the slots that are too short: every
        slot's length is measured on the features first (a chunk of trees at a time, :meth:`_long_slots`), so only
        the (typically a third) long enough slots are decoded to SRVFs and integrated. Differentiable in ``coeffs``
        like ``to_trees``.
        """
        self._check_fitted()
        k = self.n_components_
        if coeffs.shape[-1] != k:
            raise ValueError(f"coefficients must end with k={k}, got shape {tuple(coeffs.shape)}")
        if min_length is None:
            main = self.mean[: self.M * self.d].reshape(self.M, self.d) / math.sqrt(self.lambdas[0] / self.M)
            min_length = DECODE_MIN_FRACTION * float(srvf_sq_norm(main))
        c = coeffs.to(self.mean.dtype).reshape(-1, k)
        n, S, M, d = c.shape[0], self.num_slots, self.M, self.d
        MD = M * d
        tab = self._slot_tables()
        candidate = self._long_slots(c.detach(), tab, min_length)
        candidate[:, 0] = True  # the main branch is always kept
        # SRVFs of the candidate slots only (rows grouped by slot)
        slot, tree = candidate.T.nonzero().unbind(1)
        rows = SlotRows(c[tree], slot, tab.mean_q, tab.comp_q)
        s = c.new_zeros(n, S)
        if S > 1:
            s[:, 1:] = (self.mean[S * MD:] + c @ self.components[:, S * MD:]) / tab.w_s[1:].sqrt()
        root = self.mean_root.expand(n, d)
        return rows_to_trees(rows, tree * S + slot, s, root, self.slot_parent, min_length)

    def _long_slots(self, c: Tensor, tab: _SlotTables, min_length: float) -> Tensor:
        """``(n, S)``: the slots of the trees ``c (n, k)`` whose decoded squared length ``||q_j||^2 = sum |q|^2 / M``
        may exceed ``min_length`` (within a rounding margin: those are decoded and measured exactly). The features
        of ``DECODE_CHUNK_VALUES / F`` trees at a time: memory of one chunk, time ``n k F``, whatever ``k``."""
        S, M, MD = self.num_slots, self.M, self.M * self.d
        comps = self.components[:, : S * MD].to(c.dtype)
        mean = self.mean[: S * MD].to(c.dtype)
        scale = 1 / slot_weights(self.slot_depth, self.lambdas)[0].to(c)  # feature units (q sqrt(w / M)) -> |q|^2 / M
        bound = (tab.mean_norm + c.norm(dim=-1, keepdim=True) * tab.comp_norm).square()
        margin = 4 * (MD + c.shape[1] ** 2) * torch.finfo(c.dtype).eps * bound
        out = torch.empty(c.shape[0], S, dtype=torch.bool, device=c.device)
        step = max(1, DECODE_CHUNK_VALUES // max(S * MD, 1))
        for a in range(0, c.shape[0], step):
            f = torch.addmm(mean, c[a:a + step], comps).reshape(-1, S, MD)
            sq = f.square().sum(-1) * scale
            out[a:a + step] = (sq + margin[a:a + step] / M) > min_length
        return out

    def _slot_tables(self) -> _SlotTables:
        """:class:`_SlotTables` of the fit, kept until the fitted buffers change (another tensor, or one modified in
        place): several decodes of one fit (a geodesic, samples) compute them once."""
        sources = (self.mean, self.components, self.slot_depth)
        key = (tuple((id(t), t._version) for t in sources), self.lambdas, self.M, self.d)
        cached = getattr(self, "_tables", None)
        if cached is not None and cached[0] == key:
            return cached[2]
        S, M, k = self.num_slots, self.M, self.n_components_
        MD = M * self.d
        w_q, w_s = (w.to(self.mean) for w in slot_weights(self.slot_depth, self.lambdas))
        with torch.no_grad():
            unit = (w_q / M).sqrt()[:, None]
            mean_q = self.mean[: S * MD].reshape(S, MD) / unit
            comp_q = (self.components[:, : S * MD].reshape(k, S, MD) / unit).transpose(0, 1).contiguous()
            tables = _SlotTables(mean_q, comp_q, mean_q.norm(dim=-1), comp_q.norm(dim=(1, 2)), w_s)
        self._tables = (key, sources, tables)  # the sources are held so that their ids stay theirs
        return tables

    def _template(self) -> AlignedTrees:
        """An empty tree in the fitted layout (what :meth:`AlignedTrees.from_features` reads the layout from)."""
        S, dev = self.num_slots, self.mean.device
        return AlignedTrees(self.mean.new_zeros(1, S, self.M, self.d), self.mean.new_zeros(1, S),
                            torch.zeros(1, S, dtype=torch.bool, device=dev), self.mean.new_zeros(1, self.d),
                            self.slot_parent, self.slot_depth, torch.full((1, S), -1, dtype=torch.long, device=dev),
                            self.lambdas)
