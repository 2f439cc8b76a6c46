"""Per-speaker z-normalisation of features (seed 003 section 3.2, step 8)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from audio2pose_ros.errors import ConfigurationError, InputError


@dataclass
class FeatureNormalizer:
    """Per-speaker z-normalisation of features (seed 003 section 3.2 step 8).

    Attributes:
        mean: (dim,) feature means.
        std: (dim,) feature standard deviations (population, ddof 0), at least
            :attr:`STD_FLOOR`.

    """

    mean: np.ndarray
    std: np.ndarray

    # A feature that is (nearly) constant for a speaker, e.g. a band that is digital silence
    # throughout (log(eps) everywhere), has std ~ 0; dividing by it would blow noise up to huge
    # values or inf. Standard deviations are therefore floored at this value.
    STD_FLOOR: ClassVar[float] = 1e-6

    def __post_init__(self) -> None:
        """Coerce to float64 vectors and check shapes and values."""
        self.mean = np.asarray(self.mean, dtype=np.float64).reshape(-1)
        self.std = np.asarray(self.std, dtype=np.float64).reshape(-1)
        if self.mean.shape != self.std.shape:
            raise ConfigurationError(
                f"normalizer mean {self.mean.shape} and std {self.std.shape} differ in shape"
            )
        if not (np.isfinite(self.mean).all() and np.isfinite(self.std).all()):
            raise ConfigurationError("normalizer mean and std must be finite")
        if (self.std <= 0).any():
            raise ConfigurationError("normalizer std must be > 0")

    @property
    def dim(self) -> int:
        """Number of features."""
        return int(self.mean.size)

    @classmethod
    def fit(cls, frames: np.ndarray) -> FeatureNormalizer:
        """Estimate mean and std over all frames of one speaker.

        Args:
            frames: (n_frames, dim) features, n_frames >= 1.

        Returns:
            The normaliser.

        """
        x = np.asarray(frames, dtype=np.float64)
        if x.ndim != 2 or x.shape[0] == 0:
            raise ValueError(f"frames must be (n_frames >= 1, dim), got shape {x.shape}")
        if not np.isfinite(x).all():
            raise InputError("cannot fit a normalizer to non-finite feature frames")
        return cls(mean=x.mean(axis=0), std=np.maximum(x.std(axis=0), cls.STD_FLOOR))

    def apply(self, frames: np.ndarray) -> np.ndarray:
        """Normalise: (frames - mean) / std.

        Args:
            frames: (..., dim) features.

        Returns:
            (..., dim) float64 normalised features.

        """
        x = np.asarray(frames, dtype=np.float64)
        if x.shape[-1:] != (self.dim,):
            raise ValueError(f"frames must end in dimension {self.dim}, got shape {x.shape}")
        return (x - self.mean) / self.std

    def to_dict(self) -> dict[str, list[float]]:
        """JSON-safe dictionary ``{"mean": [...], "std": [...]}``."""
        return {"mean": self.mean.tolist(), "std": self.std.tolist()}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> FeatureNormalizer:
        """Rebuild from :meth:`to_dict` output.

        Args:
            data: ``{"mean": [...], "std": [...]}``.

        Returns:
            The normaliser.

        Raises:
            ConfigurationError: missing or unknown keys, or bad values.

        """
        keys = set(data)
        if keys != {"mean", "std"}:
            raise ConfigurationError(
                f"FeatureNormalizer dict needs exactly the keys ['mean', 'std'], got {sorted(keys)}"
            )
        return cls(mean=np.asarray(data["mean"]), std=np.asarray(data["std"]))
