"""Training: one engine for every run (a single run is a population of one), its loop, callbacks,
budgets, configs and seeds."""

from cartpole.agents.learner import Learner, LearnResult
from cartpole.core.errors import ConfigError
from cartpole.training.budget import Budget, parse_budget
from cartpole.training.config import TrainSettings
from cartpole.training.loop import Callback, LoopState, TrainingLoop
from cartpole.training.session import AlreadyFinished, TrainOutcome, resume, train

__all__ = [
    "AlreadyFinished",
    "Budget",
    "Callback",
    "ConfigError",
    "LearnResult",
    "Learner",
    "LoopState",
    "TrainOutcome",
    "TrainSettings",
    "TrainingLoop",
    "parse_budget",
    "resume",
    "train",
]
