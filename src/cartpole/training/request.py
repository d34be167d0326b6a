"""A training as a person asks for it, checked once for ``cartpole train`` and for the web app.

:func:`plan_training` is every check a new run goes through before anything is made (the agent, the
env, the preset, each setting, the budget, the memory), in the order ``cartpole train`` makes them:
the session starts from its :class:`TrainPlan`, and the web app's dry runs call it alone, so both
give the same one-line message for the same mistake. Each message is tagged with the input it is
about (``InputError.field``), which the web app shows it beside.

:class:`TrainRequest` is the request in the web app's terms (JSON values for settings, a list of
seeds); :func:`train_command` is the ``cartpole train`` command line that starts exactly that run,
which the web app runs and the run folder records.
"""

from __future__ import annotations

import re
from collections import Counter
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager, suppress
from dataclasses import dataclass, field, fields
from typing import Any

from cartpole.agents.presets import resolve_preset
from cartpole.agents.registry import AgentSpec, agent_names, get_agent
from cartpole.core.config import config_to_dict, field_docs, plain_value, setting_text
from cartpole.core.errors import ConfigError, InputError
from cartpole.core.memory import SHARE, describe_bytes, fits_in_memory
from cartpole.core.seeding import MAX_TRAIN_SEED, describe_seeds
from cartpole.envs import EnvInfo, env_info
from cartpole.training.budget import Budget, check_budget_unit, parse_budget
from cartpole.training.config import TrainSettings, resolve_config

MAX_SEEDS = 4096
"""More seeds than this in one process: split them (each seed holds a run folder and a status thread)."""

DEFAULT_ENV = "CartPole-v1"
DEFAULT_RUNS_DIR = "runs"


@dataclass(frozen=True)
class TrainPlan:
    """What a new training is built from, every part checked."""

    spec: AgentSpec
    env: EnvInfo
    preset: str
    config: Any
    settings: TrainSettings
    budget: Budget


@contextmanager
def about(input_name: str) -> Iterator[None]:
    """Tag an InputError raised inside with ``input_name``, unless it already names its input."""
    try:
        yield
    except InputError as err:
        if err.field is None:
            err.field = input_name
        raise


def plan_training(
    agent: str,
    env_id: str,
    seeds: int,
    *,
    preset: str | None = None,
    overrides: Mapping[str, Any] | None = None,
    budget: Budget | str | None = None,
    stop_when_solved: bool | None = None,
) -> TrainPlan:
    """Check a new training of ``seeds`` seeds and resolve its parts; InputError (tagged with its
    input) at the first problem. ``overrides`` are setting values, as ``--set`` text or as JSON values."""
    with about("agent"):
        if agent not in agent_names():
            raise ConfigError(f"unknown agent {agent!r}; choose one of: {', '.join(agent_names())}")
        spec = get_agent(agent)
    with about("env_id"):
        env = env_info(env_id)
        spec.check_env(env)  # before its memory estimate: that of an agent that cannot take the env is moot
    with about("preset"):
        preset = resolve_preset(agent, env, preset)
    with about("settings"):
        try:
            config, settings = resolve_config(agent, spec.config_cls, preset, dict(overrides or {}))
        except InputError as err:
            err.field = err.field or setting_named(str(err), spec)
            raise
    if settings.env_kwargs or settings.wrappers:
        with about("env_kwargs" if settings.env_kwargs else "wrappers"):
            env = env_info(env_id, settings.env_kwargs, settings.wrappers)  # the env as configured
            spec.check_env(env)
    if stop_when_solved is not None:
        settings.stop_when_solved = stop_when_solved
    with about("budget"):
        if isinstance(budget, str):
            budget = parse_budget(budget)
        budget = budget or parse_budget(settings.budget)
        check_budget_unit(budget, agent, spec.iteration)
    try:
        check_memory(spec, config, env, seeds)
    except InputError as err:
        err.field = err.field or memory_field(spec, env, seeds, preset, dict(overrides or {}))
        raise
    return TrainPlan(spec, env, preset, config, settings, budget)


_LEADING_NAME = re.compile(r"^([a-z_][a-z0-9_]*)\b")


def setting_named(message: str, spec: AgentSpec) -> str | None:
    """The setting a config's message is about: the settings' checks start with its name
    (``lr must be > 0``, ``eval_every='x' is not a valid int``); None if it names none."""
    match = _LEADING_NAME.match(message)
    return match.group(1) if match and match.group(1) in setting_names(spec) else None


def setting_names(spec: AgentSpec) -> set[str]:
    return {f.name for f in fields(spec.config_cls)} | {f.name for f in fields(TrainSettings)}


def memory_field(spec: AgentSpec, env: EnvInfo, seeds: int, preset: str, overrides: dict[str, Any]) -> str:
    """The input a training too big for the memory is about: the first setting given without which
    it fits (an oversized ``hidden_sizes``); else ``seeds`` when one seed fits; else ``settings``
    (several given settings together), or ``preset`` when none is given."""
    for name in overrides:
        rest = {key: value for key, value in overrides.items() if key != name}
        try:
            config, _ = resolve_config(spec.name, spec.config_cls, preset, rest)
            check_memory(spec, config, env, seeds)
        except InputError:
            continue
        return name
    if seeds > 1:
        config, _ = resolve_config(spec.name, spec.config_cls, preset, overrides)
        with suppress(InputError):
            check_memory(spec, config, env, 1)
            return "seeds"
    return "settings" if overrides else "preset"


def check_memory(spec: AgentSpec, config: Any, env: EnvInfo, seeds: int) -> None:
    """InputError, before anything is allocated, when ``seeds`` seeds of ``spec`` with ``config`` on
    ``env`` will not fit in the memory available (the agent's own estimate of a seed's bytes)."""
    needed = spec.bytes_per_seed(config, env) * seeds
    fits, free = fits_in_memory(needed)
    if fits or free is None:
        return
    what = "this run" if seeds == 1 else f"{seeds} seeds"
    fewer = "" if seeds == 1 else f"fewer seeds (about {int(seeds * SHARE * free / needed)} fit) or "
    raise InputError(
        f"{what} of {spec.name} would take about {describe_bytes(needed)} of memory but "
        f"{describe_bytes(free)} is available; use {fewer}smaller settings"
    )


_RANGE = re.compile(r"^(\d+)-(\d+)$")
SEEDS_HINT = "give a count (5: seeds 0-4), a range (0-99), a list (3,5,8) or both (0-9,20)"


def is_seed_count(text: str) -> bool:
    """Whether ``--seeds`` text is a count (a number alone) rather than seeds named by range or list."""
    return text.strip().isdigit()


def parse_seeds(text: str, first: int = 0) -> list[int]:
    """The seeds ``--seeds`` names, with one meaning in train, compare and sweep: a number alone is a
    count (``10``: seeds ``first`` to ``first + 9``); a range (``0-99``, inclusive), a list
    (``3,5,8``) or both (``0-9,20``) name the seeds. InputError on anything else: empty, malformed,
    a count of none, reversed ranges, duplicates, seeds out of range, ``first`` with named seeds."""
    if not text.strip():
        raise InputError(f"--seeds is empty; {SEEDS_HINT}")
    if is_seed_count(text):
        count = int(text)
        if count < 1:
            raise InputError(f"--seeds {count} is a count of no seeds; {SEEDS_HINT} (one seed: N-N)")
        if count > MAX_SEEDS:
            raise InputError(f"--seeds asks for more than {MAX_SEEDS} seeds; split them into several runs")
        return check_seed_range(list(range(first, first + count)))
    if first:
        raise InputError(
            f"--first-seed shifts a count of seeds (--seeds N), but --seeds {text.strip()} names its "
            "seeds already; drop --first-seed"
        )
    seeds: list[int] = []
    for part in text.split(","):
        part = part.strip()
        match = _RANGE.match(part)
        if match:
            low, high = int(match.group(1)), int(match.group(2))
            if low > high:
                raise InputError(f"--seeds range {part!r} is reversed; write {high}-{low}")
            if len(seeds) + high - low + 1 > MAX_SEEDS:
                raise InputError(
                    f"--seeds asks for more than {MAX_SEEDS} seeds; split them into several runs"
                )
            seeds += range(low, high + 1)
        elif part.isdigit():
            seeds.append(int(part))
        else:
            raise InputError(f"--seeds {text!r}: {part!r} is not a seed or a range; {SEEDS_HINT}")
        if len(seeds) > MAX_SEEDS:
            raise InputError(f"--seeds asks for more than {MAX_SEEDS} seeds; split them into several runs")
    duplicates = sorted(seed for seed, count in Counter(seeds).items() if count > 1)
    if duplicates:
        raise InputError(f"--seeds lists seed {duplicates[0]} more than once; each seed trains once")
    return check_seed_range(seeds)


def check_seed_range(seeds: list[int]) -> list[int]:
    """``seeds``, or InputError naming the first out of training's range."""
    out_of_range = [s for s in seeds if not 0 <= s <= MAX_TRAIN_SEED]
    if out_of_range:
        raise InputError(f"seed {out_of_range[0]} is out of range; seeds are 0 to {MAX_TRAIN_SEED}")
    return seeds


# ----------------------------------------------------------------------------------------------
# The web app's request, and the command it stands for
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class TrainRequest:
    """A new training: one run (one seed) or a population (several seeds, a run folder each)."""

    agent: str
    env_id: str = DEFAULT_ENV
    preset: str | None = None
    """A named preset of the agent; None: the env's (as ``cartpole train`` picks it)."""
    seeds: tuple[int, ...] = (0,)
    budget: str | None = None
    """As ``--budget`` takes it; None: the preset's."""
    settings: Mapping[str, Any] = field(default_factory=dict)
    """Setting name -> JSON value (number, boolean, string, list), as ``--set`` would give it."""
    runs_dir: str = DEFAULT_RUNS_DIR

    @property
    def population(self) -> bool:
        return len(self.seeds) > 1


NOT_FROM_THE_APP = ("env_kwargs", "wrappers")
"""Settings the web app neither shows nor takes: they would make the server import or pass what the
app does not list (an env's constructor arguments, wrapper classes); the command line takes them."""


def parse_env_kwargs(pairs: Sequence[str]) -> dict[str, Any]:
    """``--env-kwargs KEY=VALUE ...`` as a table: each value read as ``--set`` reads text
    (:func:`~cartpole.core.config.plain_value`); InputError for a pair that is not KEY=VALUE."""
    kwargs: dict[str, Any] = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or not key.strip().isidentifier():
            raise InputError(f"--env-kwargs expects KEY=VALUE with KEY a keyword name, got {pair!r}")
        kwargs[key.strip()] = plain_value(value.strip())
    return kwargs


def check_request(request: TrainRequest) -> TrainPlan:
    """``plan_training`` for ``request``, after the checks of its seeds and settings; InputError tagged
    with its input."""
    with about("seeds"):
        check_seeds(request.seeds)
    for name in NOT_FROM_THE_APP:
        if name in request.settings:
            error = InputError(
                f"{name} cannot be set from the web app: use cartpole train with a preset file"
            )
            error.field = name
            raise error
    return plan_training(
        request.agent,
        request.env_id,
        len(request.seeds),
        preset=request.preset,
        overrides=request.settings,
        budget=request.budget,
    )


def check_seeds(seeds: tuple[int, ...]) -> None:
    """InputError unless ``seeds`` are some training seeds, each once (the messages ``--seeds`` gets)."""
    if not seeds:
        raise InputError("no seeds to train: give one seed or more")
    if len(seeds) > MAX_SEEDS:
        raise InputError(f"more than {MAX_SEEDS} seeds; split them into several runs")
    check_seed_range(list(seeds))
    repeated = sorted(seed for seed, count in Counter(seeds).items() if count > 1)
    if repeated:
        raise InputError(f"seed {repeated[0]} is listed more than once; each seed trains once")


def train_command(request: TrainRequest) -> list[str]:
    """The ``cartpole train`` command line that starts ``request``'s training (its run folders
    record it, so it can be run again from a terminal)."""
    argv = ["cartpole", "train", request.agent]
    if request.env_id != DEFAULT_ENV:
        argv += ["--env", request.env_id]
    if request.preset is not None:
        argv += ["--preset", request.preset]
    if request.population:
        argv += ["--seeds", describe_seeds(list(request.seeds))]
    elif request.seeds[0] != 0:
        argv += ["--seed", str(request.seeds[0])]
    if request.budget is not None:
        argv += ["--budget", request.budget]
    for name, value in request.settings.items():
        argv += ["--set", f"{name}={setting_text(value)}"]
    if request.runs_dir != DEFAULT_RUNS_DIR:
        argv += ["--runs-dir", request.runs_dir]
    return argv


# ----------------------------------------------------------------------------------------------
# What a form shows
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Setting:
    """One setting of a preset, as a form shows it."""

    name: str
    value: Any
    kind: str
    """bool, int, float, str or list (the field's type; "|none" when it may be none)."""
    doc: str


@dataclass(frozen=True)
class PresetForm:
    """A preset as a form shows it."""

    preset: str
    budget: str
    settings: list[Setting]


def preset_settings(agent: str, env_id: str, preset: str | None) -> PresetForm:
    """The preset ``agent`` trains with on ``env_id`` (``preset``, or the env's), its budget and every
    other setting it gives, the agent's then the training's, each with its value and its one-line
    doc; InputError (tagged) if the agent, env or preset cannot be used."""
    plan = plan_training(agent, env_id, 1, preset=preset)
    shown = []
    for cls, values in ((plan.spec.config_cls, plan.config), (TrainSettings, plan.settings)):
        docs, kinds = field_docs(cls), {f.name: f.type for f in fields(cls)}
        for name, value in config_to_dict(values).items():
            if cls is TrainSettings and name in ("budget", *NOT_FROM_THE_APP):
                continue  # the form's budget field; what the app does not take
            shown.append(Setting(name, value, kind_of(str(kinds[name])), docs[name]))
    return PresetForm(plan.preset, plan.settings.budget, shown)


def kind_of(annotation: str) -> str:
    """A field's annotation (text, as ``from __future__ import annotations`` keeps it) as a form's kind."""
    parts = [p.strip() for p in annotation.split("|")]
    nullable = "None" in parts
    base = next((p for p in parts if p != "None"), "str")
    kind = next((k for k in ("bool", "int", "float", "str") if base == k), "list")
    return f"{kind}|none" if nullable else kind
