"""Presets are data; bad settings and budgets are rejected with one clear line."""

from __future__ import annotations

import pytest

from cartpole.agents.presets import preset_names
from cartpole.agents.registry import agents
from cartpole.training import Budget, ConfigError, parse_budget
from cartpole.training.config import resolve_config


@pytest.mark.parametrize("agent", ["random-search", "hill-climbing", "cem"])
def test_every_preset_resolves(agent):
    spec = agents()[agent]
    for preset in preset_names(agent):
        config, settings = resolve_config(agent, spec.config_cls, preset)
        assert config is not None and settings.eval_episodes >= 1


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        ({"population": "0"}, "population must be >= 1"),
        ({"popluation": "5"}, "unknown setting 'popluation'"),
        ({"population": "many"}, "population='many' is not a valid"),
        ({"elite_fraction": "1.5"}, "elite_fraction"),
        ({"budget": "forever"}, "bad budget"),
    ],
)
def test_bad_settings(overrides, message):
    with pytest.raises(ConfigError if "budget" not in overrides else ValueError, match=message):
        resolve_config("cem", agents()["cem"].config_cls, "default", overrides)


def test_unknown_preset():
    with pytest.raises(ConfigError, match="unknown preset 'nope' for cem; choose one of: default"):
        resolve_config("cem", agents()["cem"].config_cls, "nope")


@pytest.mark.parametrize(
    ("text", "budget"),
    [
        ("50000", Budget(env_steps=50000)),
        ("50k", Budget(env_steps=50000)),
        ("1e5", Budget(env_steps=100000)),
        ("300ep", Budget(episodes=300)),
        ("20gen", Budget(iterations=20)),
        ("90s", Budget(seconds=90.0)),
        ("2min", Budget(seconds=120.0)),
    ],
)
def test_budgets(text, budget):
    assert parse_budget(text) == budget


@pytest.mark.parametrize("text", ["", "-5", "0", "5 parsecs", "ten"])
def test_bad_budgets(text):
    with pytest.raises(ValueError, match="bad budget"):
        parse_budget(text)
