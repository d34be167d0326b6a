"""Presets: named settings of each agent, kept as data in ``presets/<agent>.toml``, or preset files.

A preset file is a ``.toml`` file anywhere (for example the ``best.toml`` a sweep writes) holding one
table of settings, or exactly one named table of them. Which named preset an agent takes on an env
when none is named is data too: ``presets/by_env.toml`` (:func:`resolve_preset`), which also says
which presets are made for image observations.
"""

from __future__ import annotations

import tomllib
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any

from cartpole.core.errors import ConfigError

if TYPE_CHECKING:
    from cartpole.envs import EnvInfo

DEFAULT_PRESET = "default"
BY_ENV = "by_env.toml"
TABLE_SETTINGS = ("env_kwargs",)
"""Settings whose value is a table: in a preset file they are settings, not a named preset."""


def preset_table(agent: str) -> dict[str, dict[str, Any]]:
    """All presets of ``agent`` as read from its TOML file."""
    text = resources.files("cartpole.agents").joinpath("presets", f"{agent}.toml").read_text(encoding="utf-8")
    return tomllib.loads(text)


def preset_names(agent: str) -> list[str]:
    return list(preset_table(agent))


def preset_source(agent: str) -> str:
    """Where ``agent``'s named presets are read from (a file path, for ``cartpole presets``)."""
    return str(resources.files("cartpole.agents").joinpath("presets", f"{agent}.toml"))


def is_preset_file(preset: str) -> bool:
    """A preset given as a path to a TOML file (``best.toml``, ``my/preset.toml``) rather than a name."""
    return preset.endswith(".toml")


def read_preset_file(path: str | Path) -> dict[str, Any]:
    """The settings of a preset file: one table of settings (the form ``cartpole sweep`` writes as
    ``best.toml``), or a file holding exactly one named table of them."""
    path = Path(path)
    try:
        table = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"preset file {path} does not exist") from None
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as err:
        raise ConfigError(f"preset file {path} is not readable TOML: {err}") from None
    tables = [v for k, v in table.items() if isinstance(v, dict) and k not in TABLE_SETTINGS]
    if tables and len(tables) == len(table):
        if len(tables) > 1:
            raise ConfigError(
                f"preset file {path} holds {len(tables)} presets ({', '.join(table)}); keep one table"
            )
        return tables[0]
    return table


def preset_values(agent: str, preset: str) -> dict[str, Any]:
    """The settings a preset sets (without its description): by name, or from a ``.toml`` file."""
    if is_preset_file(preset):
        values = read_preset_file(preset)
    else:
        table = preset_table(agent)
        if preset not in table:
            raise ConfigError(
                f"unknown preset {preset!r} for {agent}; choose one of: {', '.join(table)} "
                "(or give a path to a .toml preset file)"
            )
        values = table[preset]
    return {k: v for k, v in values.items() if k != "description"}


# --- which preset on which env: presets/by_env.toml ------------------------------------------


def presets_by_env() -> dict[str, dict[str, str]]:
    """Env id -> {agent: the preset it takes there when none is named}, as ``by_env.toml`` lists them."""
    env_table: dict[str, dict[str, str]] = _by_env_table()["env"]
    return env_table


def by_env_source() -> str:
    """Where the table of presets by env is read from (a file path, for ``cartpole presets``)."""
    return str(resources.files("cartpole.agents").joinpath("presets", BY_ENV))


def _by_env_table() -> dict[str, Any]:
    return tomllib.loads(
        resources.files("cartpole.agents").joinpath("presets", BY_ENV).read_text(encoding="utf-8")
    )


def image_presets(agent: str) -> list[str]:
    """The named presets of ``agent`` made for image observations (every other one is for state vectors)."""
    images: dict[str, list[str]] = _by_env_table()["images"]
    return list(images.get(agent, []))


def env_preset(agent: str, env_id: str) -> str:
    """The preset ``agent`` takes on ``env_id`` when none is named: by_env.toml's, else "default"."""
    return presets_by_env().get(env_id, {}).get(agent, DEFAULT_PRESET)


def picked_preset_line(agent: str, env_id: str) -> str | None:
    """The line saying which preset ``agent`` takes on ``env_id`` when none is named; None when it is
    the agent's "default" (nothing to say)."""
    preset = env_preset(agent, env_id)
    if preset == DEFAULT_PRESET:
        return None
    return f"preset: {preset} ({agent}'s preset for {env_id}, {BY_ENV}; --preset NAME for another)"


def resolve_preset(agent: str, env: EnvInfo, preset: str | None) -> str:
    """The preset ``agent`` trains with on ``env``: ``preset``, or when None the env's own
    (:func:`env_preset`). ConfigError, in one line, for a named preset made for another kind of
    observation than ``env`` gives (a preset file is taken as it is)."""
    chosen = env_preset(agent, env.env_id) if preset is None else preset
    if is_preset_file(chosen):
        return chosen
    for_images = image_presets(agent)
    if env.is_image == (chosen in for_images):
        return chosen
    if env.is_image:
        kind = f"images {list(env.obs_shape)}"
        fix = f"use --preset {' or '.join(for_images)}" if for_images else _no_image_preset(agent)
        if preset is None:
            raise ConfigError(f"{_no_image_preset(agent)} ({env.env_id}'s observations are {kind})")
        raise ConfigError(
            f"preset {chosen!r} of {agent} is made for state vectors, but {env.env_id}'s observations "
            f"are {kind}; {fix}"
        )
    raise ConfigError(
        f"preset {chosen!r} of {agent} is made for image observations, but {env.env_id}'s observations "
        f"are state vectors {list(env.obs_shape)}; use --preset {env_preset(agent, env.env_id)} or "
        "another of its presets for state vectors"
    )


def _no_image_preset(agent: str) -> str:
    able = list(_by_env_table()["images"])
    return (
        f"{agent} has no preset for images: give it a preset file (--preset FILE.toml), or train "
        f"{' or '.join(able)} with theirs"
    )
