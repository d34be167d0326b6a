"""The best trial of a sweep as a preset file, ``D/sweeps/NAME/best.toml``, and finding those files."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from cartpole.runs.atomic import write_text_atomic

if TYPE_CHECKING:
    from cartpole.experiments.sweep_spec import SweepSpec


def best_value(study: Any) -> Any:
    from optuna.trial import TrialState

    complete = study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
    return min(complete, key=lambda t: t.value) if complete else None


def best_preset(spec: SweepSpec, trial: Any) -> dict[str, Any]:
    """The best trial as a complete preset: the sweep's preset with the trial's settings."""
    from cartpole.agents.presets import preset_values
    from cartpole.agents.registry import get_agent
    from cartpole.core.config import config_to_dict
    from cartpole.core.seeding import describe_seeds
    from cartpole.training.config import resolve_config

    config, settings = resolve_config(spec.agent, get_agent(spec.agent).config_cls, spec.preset, trial.params)
    resolved = config_to_dict(config) | config_to_dict(settings)
    values = preset_values(spec.agent, spec.preset) | {k: resolved[k] for k in trial.params}
    if spec.budget:
        values["budget"] = spec.budget
    if spec.env_kwargs:  # the env the trials trained on: a train with this preset trains there too
        values["env_kwargs"] = resolved["env_kwargs"] | spec.env_kwargs
    values = {k: "none" if v is None else v for k, v in values.items()}
    description = (
        f"cartpole sweep {spec.name} ({spec.agent}, from preset {Path(spec.preset).name}): trial "
        f"{trial.number}, median {trial.value:,.0f} env steps to a verified solve over seeds "
        f"{describe_seeds(spec.trial_seeds)}"
    )
    return {"description": description, **values}


def write_best(spec: SweepSpec, study: Any) -> Path | None:
    """``best.toml`` from the best complete trial (None while there is none)."""
    import tomli_w

    best = best_value(study)
    if best is None:
        return None
    text = tomli_w.dumps(best_preset(spec, best))
    path = spec.path / "best.toml"
    write_text_atomic(path, text)
    return path


@dataclass(frozen=True)
class SweepPreset:
    """A best.toml that a sweep wrote, for ``cartpole presets``."""

    path: Path
    agent: str
    values: dict[str, Any]


def sweep_presets(runs_dir: Path) -> list[SweepPreset]:
    """Every ``sweeps/NAME/best.toml`` under ``runs_dir`` with the agent its sweep tuned."""
    import tomllib

    found = []
    for best in sorted((runs_dir / "sweeps").glob("*/best.toml")):
        try:
            agent = json.loads((best.parent / "sweep.json").read_text(encoding="utf-8"))["agent"]
            values = tomllib.loads(best.read_text(encoding="utf-8"))
        except (OSError, ValueError, KeyError):
            continue
        found.append(SweepPreset(best, agent, values))
    return found
