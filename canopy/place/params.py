"""Typed parameters of vocabulary training (one frozen dataclass, YAML section ``vocabulary``)."""
from __future__ import annotations

from dataclasses import dataclass

from shared.errors import ConfigError

# DBoW2's enum orders (TemplatedVocabulary.h): the integers written in the file header.
WEIGHTINGS = ("tf_idf", "tf", "idf", "binary")
SCORINGS = ("l1", "l2", "chi_square", "kl", "bhattacharyya", "dot_product")


@dataclass(frozen=True)
class VocabularyParams:
    k: int = 10                  # branching factor (DBoW2 / ORB-SLAM: 10)
    levels: int = 5              # depth L below the root; k**L leaves at most
    seed: int = 0                # k-means++ seeding draws
    max_iterations: int = 10     # k-majority rounds per node (DBoW2 runs to convergence;
                                 # assignments rarely change after a few rounds)
    weighting: str = "tf_idf"
    scoring: str = "l1"

    def validate(self) -> None:
        # DBoW2's loader refuses k > 20 or L > 10 (loadFromTextFile), so do we.
        if not 2 <= self.k <= 20:
            raise ConfigError("vocabulary.k", f"must be in [2, 20], got {self.k}")
        if not 1 <= self.levels <= 10:
            raise ConfigError("vocabulary.levels", f"must be in [1, 10], got {self.levels}")
        if self.max_iterations < 1:
            raise ConfigError("vocabulary.max_iterations", f"must be >= 1, got {self.max_iterations}")
        if self.weighting not in WEIGHTINGS:
            raise ConfigError("vocabulary.weighting", f"must be one of {WEIGHTINGS}, got {self.weighting!r}")
        if self.scoring not in SCORINGS:
            raise ConfigError("vocabulary.scoring", f"must be one of {SCORINGS}, got {self.scoring!r}")
