"""The space of 3D trees (docs/method.md §4): the Karcher mean in a growing slot layout and tree PCA on its features."""

from .fitted import NotFittedError
from .karcher import KarcherMean, MeanRegistration, SlotLimitError
from .pca import TreePCA

__all__ = ["KarcherMean", "MeanRegistration", "NotFittedError", "SlotLimitError", "TreePCA"]
