"""The interface every position estimator implements (PF-DOA, the paper's comparison methods)."""

from __future__ import annotations

from abc import ABC, abstractmethod

# The shared records live in pfdoa.types (the lowest floor); estimator code imports them from here.
from pfdoa.types import Estimate, Observation, Odometry

__all__ = ["Estimate", "Estimator", "Observation", "Odometry"]


class Estimator(ABC):
    """Stateful position estimator. ``step`` is called once per observation, in time order."""

    name: str = ""
    uses_rng: bool = False  # make_estimator hands such a method the caller's generator

    @abstractmethod
    def reset(self) -> None:
        """Forget all state (as after construction)."""

    @abstractmethod
    def step(self, obs: Observation, odom: Odometry | None = None) -> Estimate:
        """Consume one observation (and the odometry since the previous one)."""
