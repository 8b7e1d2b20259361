"""Seeded target trajectories (the paper's scenario and simple named ones) and their measurements."""

from kalmix.scenarios.paper import (
    SCENARIOS,
    CircleScenario,
    PaperScenario,
    RandomWalkScenario,
    Scenario,
    Trajectory,
    paper_measurements,
)

__all__ = [
    "SCENARIOS",
    "CircleScenario",
    "PaperScenario",
    "RandomWalkScenario",
    "Scenario",
    "Trajectory",
    "paper_measurements",
]
