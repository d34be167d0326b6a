"""Presets are data; bad settings and budgets are rejected with one clear line."""

from __future__ import annotations

import pytest

from cartpole.agents.presets import preset_table
from cartpole.agents.registry import agent_names, agents, get_agent
from cartpole.training import Budget, ConfigError, TrainSettings, parse_budget
from cartpole.training.config import resolve_config


@pytest.mark.parametrize("agent", agent_names())
def test_every_preset_value_reaches_the_config_and_the_settings(agent):
    spec = get_agent(agent)
    for preset, table in preset_table(agent).items():
        config, settings = resolve_config(agent, spec.config_cls, preset)
        for key, value in table.items():
            if key == "description":
                continue
            resolved = getattr(config, key) if hasattr(config, key) else getattr(settings, key)
            expected = None if value == "none" else as_tuples(value)
            assert resolved == expected, (preset, key)


@pytest.mark.parametrize("agent", agent_names())
def test_every_agents_default_preset_counts_a_solve_only_when_it_is_confirmed(agent):
    """A passing evaluation counts, and stops training, only when the next 100 episodes pass too."""
    _, settings = resolve_config(agent, get_agent(agent).config_cls, "default")
    assert settings.confirm_solves and settings.stop_when_solved


def as_tuples(value):
    """A TOML value as a config holds it: lists (and lists of lists) as tuples."""
    return tuple(as_tuples(v) for v in value) if isinstance(value, list) else value


def test_an_override_beats_the_preset_and_the_preset_beats_the_default():
    spec = get_agent("cem")
    default_config, default_settings = spec.config_cls(), TrainSettings()
    config, settings = resolve_config("cem", spec.config_cls, "default", {"population": "7"})
    assert config.population == 7 != preset_table("cem")["default"]["population"]
    assert settings.budget == preset_table("cem")["default"]["budget"] != default_settings.budget
    assert config.bias == default_config.bias  # not in the preset: the dataclass default


@pytest.mark.parametrize(
    ("text", "hidden_sizes", "conv_layers"),
    [
        ("256,256", (256, 256), None),
        ("[256, 256]", (256, 256), None),  # as the presets and `cartpole presets` write it
        ("[]", (), None),
        ("[[16, 8, 4], [32, 3, 1]]", None, ((16, 8, 4), (32, 3, 1))),
    ],
)
def test_a_list_setting_from_the_command_line_as_commas_or_as_a_toml_array(text, hidden_sizes, conv_layers):
    key = "conv_layers" if conv_layers else "hidden_sizes"
    config, _ = resolve_config("dqn", get_agent("dqn").config_cls, "default", {key: text})
    assert getattr(config, key) == (conv_layers or hidden_sizes)


def test_a_broken_list_setting_is_one_line():
    with pytest.raises(ConfigError, match=r"hidden_sizes='\[256,' is not a valid tuple\[int, ...\]"):
        resolve_config("dqn", get_agent("dqn").config_cls, "default", {"hidden_sizes": "[256,"})


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
