"""What the gap search found: the candidates it scored and the diagnosis it reports (:mod:`.search`)."""

from __future__ import annotations

from dataclasses import dataclass, field

from lidar_weather_sim.scenario.effects import Effect


@dataclass
class Candidate:
    """A fitted candidate: the effect at its best value, its calibration and held-out gaps."""

    effect: Effect
    fit_gap: float
    heldout_gap: float
    evaluations: int
    companions: tuple[Effect, ...] | None = None  # the accepted effects as set for it (None: as they were)


@dataclass
class Diagnosis:
    """The search's result: the held-out gap before and after, the accepted effects (each with the held-out gap
    before it), those rejected, every round's candidates and the frames used."""

    gap_before: float
    gap_after: float
    accepted: list[tuple[Candidate, float]] = field(default_factory=list)  # (candidate, gap before it)
    rejected: list[Candidate] = field(default_factory=list)
    rounds: list[list[Candidate]] = field(default_factory=list)
    fit_indices: list[int] = field(default_factory=list)
    heldout_indices: list[int] = field(default_factory=list)

    @property
    def effects(self) -> list[Effect]:
        return [c.effect for c, _ in self.accepted]


def same_effect(a: Effect, b: Effect) -> bool:
    """The same effect (and the same emitter for spray)."""
    return a.name == b.name and a.params.get("actor") == b.params.get("actor")
