"""The JSON API that starts, stops and resumes trainings (``web/trainings.py``), see /openapi.json.

Every POST here needs the server's token and the page's own origin (``security.TokenGate``). What a
request may name comes from the app's own lists: an env of :data:`~cartpole.web.envs.OFFERED_ENVS`
(checked before anything looks it up), an agent, one of its named presets (never a file), settings of
that preset (never an import path); the checks and their messages are ``cartpole train``'s
(:func:`cartpole.training.request.check_request`). The web app's JSON is strict where the command
line's text cannot be: seeds and integer settings are JSON integers, each setting a value of its own
JSON type (:func:`check_json_types`). Answers show the runs folder as the pages do, never where it is
on this machine (:func:`~cartpole.web.answers.shown_paths`).
"""

from __future__ import annotations

import asyncio
import os
import time
import types
import typing
from collections.abc import Mapping
from dataclasses import fields
from typing import Annotated, Any

from fastapi import APIRouter, HTTPException, Path, Query, Request
from fastapi.responses import JSONResponse
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    StrictBool,
    StrictFloat,
    StrictInt,
    StrictStr,
    ValidationError,
    ValidatorFunctionWrapHandler,
    WrapValidator,
)
from pydantic_core import PydanticCustomError

from cartpole.agents.presets import image_presets, preset_table
from cartpole.agents.registry import DEFAULT_AGENT, agent_names, get_agent
from cartpole.core.errors import ConfigError, InputError
from cartpole.training.config import TrainSettings
from cartpole.training.request import (
    DEFAULT_ENV,
    MAX_SEEDS,
    TrainRequest,
    about,
    check_request,
    preset_settings,
    train_command,
)
from cartpole.web.answers import Refusal, refusal, shown_paths, shown_value
from cartpole.web.envs import OFFERED_ENVS, offered
from cartpole.web.trainings import TrainingError, Trainings, TrainingState

router = APIRouter(prefix="/api")

START_WAIT_SECONDS = 30.0
"""How long a start waits for its process to name its run folders before it answers without them."""
MAX_SETTINGS = 200
MAX_TEXT = 200

SETTING_VALUES = f"true or false, a number, text of at most {MAX_TEXT} characters, a list or null"


def _one_setting_error(value: Any, handler: ValidatorFunctionWrapHandler) -> Any:
    """A setting's value, or one error for it (not one for each kind of JSON value it is not)."""
    try:
        return handler(value)
    except ValidationError:
        raise PydanticCustomError(
            "setting_value",
            "must be {kinds}, got {got}",
            {"kinds": SETTING_VALUES, "got": shown_value(value)},
        ) from None


JSONValue = Annotated[
    StrictBool
    | StrictInt
    | StrictFloat
    | Annotated[StrictStr, Field(max_length=MAX_TEXT)]
    | list[Any]
    | None,
    WrapValidator(_one_setting_error),
]


class TrainingIn(BaseModel):
    """A training to start: what ``cartpole train`` takes, as JSON."""

    model_config = ConfigDict(extra="forbid")

    agent: Annotated[str, Field(max_length=MAX_TEXT, description="an agent, as `cartpole train AGENT`")]
    env_id: Annotated[
        str | None, Field(max_length=MAX_TEXT, description=f"one of {', '.join(OFFERED_ENVS)}")
    ] = None
    preset: Annotated[
        str | None, Field(max_length=MAX_TEXT, description="a named preset of the agent (default: the env's)")
    ] = None
    seeds: Annotated[
        list[StrictInt] | None,
        Field(
            max_length=MAX_SEEDS,
            description="training seeds, JSON integers; one: a run; several: a population (--seeds)",
        ),
    ] = None
    budget: Annotated[
        str | None, Field(max_length=MAX_TEXT, description="as --budget takes it: 50k, 300ep, 20gen, 90s")
    ] = None
    settings: Annotated[
        dict[str, JSONValue],
        Field(max_length=MAX_SETTINGS, description="setting name -> value, as --set KEY=VALUE would give it"),
    ] = {}
    dry_run: StrictBool = Field(False, description="check only: start nothing, answer with the command")


class TrainingRow(BaseModel):
    name: str
    state: TrainingState
    runs: list[str] = Field(description="its run folders' names ([] until its process has made them)")
    agent: str | None = None
    env_id: str | None = None
    seeds: list[int] | None = None
    created: str | None = None
    command: list[str] = Field(
        default_factory=list,
        description="the `cartpole train` command it runs, the runs folder as the pages show it",
    )
    request: dict[str, Any] = Field(
        default_factory=dict, description="what was asked (runs_dir: the runs folder as the pages show it)"
    )
    problem: str | None = Field(None, description="why it failed, in one line")
    queue_position: int | None = Field(None, description="1: the next to start")


class TrainingStarted(BaseModel):
    name: str | None = Field(description="the training's name (null for a dry run)")
    runs: list[str]
    state: str = Field(description="queued or running (checked, for a dry run)")
    command: list[str] = Field(
        description="the `cartpole train` command, the runs folder as the pages show it"
    )


BAD: dict[int | str, dict[str, Any]] = {
    422: {"model": Refusal, "description": "a bad request; nothing started"}
}
Name = Annotated[str, Path(max_length=MAX_TEXT)]


def trainings(request: Request) -> Trainings:
    found: Trainings | None = request.app.state.trainings
    if found is None:
        raise HTTPException(403, "this server is read-only (cartpole serve --read-only): it starts nothing")
    return found


def bad_request(err: InputError) -> JSONResponse:
    return refusal(422, err, err.field)


def shown(request: Request, value: Any) -> Any:
    """An answer's value with the runs folder as the pages show it (no path of this machine)."""
    return shown_paths(value, request.app.state.runs.root)


def to_request(body: TrainingIn, runs_dir: str) -> TrainRequest:
    """The request, or InputError for what the app does not offer (another env, a preset file). The
    env is compared with the app's list before anything looks it up (nothing it names is imported)."""
    env_id = body.env_id or DEFAULT_ENV
    with about("env_id"):
        if not offered(env_id):
            raise ConfigError(
                f"env {env_id!r} is not one the web app trains: choose one of {', '.join(OFFERED_ENVS)} "
                "(other envs train with `cartpole train --env`)"
            )
    with about("agent"):
        if body.agent not in agent_names():
            raise ConfigError(f"unknown agent {body.agent!r}; choose one of: {', '.join(agent_names())}")
    with about("preset"):
        presets = list(preset_table(body.agent))
        if body.preset is not None and body.preset not in presets:
            raise ConfigError(
                f"unknown preset {body.preset!r} for {body.agent}; choose one of: {', '.join(presets)}"
            )
    seeds = tuple(body.seeds) if body.seeds is not None else (0,)
    return TrainRequest(body.agent, env_id, body.preset, seeds, body.budget, dict(body.settings), runs_dir)


@router.post("/trainings", status_code=201, response_model=TrainingStarted, responses=BAD)
async def start_training(request: Request, body: TrainingIn) -> Any:
    """Start a training (or queue it, when ``--max-trainings`` are running): the run that
    ``cartpole train`` with the same choices starts, in a process of its own."""
    manager = None if body.dry_run else trainings(request)
    try:
        train = to_request(body, str(request.app.state.runs.root))
        await asyncio.to_thread(check_request, train)
        check_json_types(train)
    except InputError as err:
        return bad_request(err)
    if manager is None:
        command = shown(request, train_command(train))
        return JSONResponse({"name": None, "runs": [], "state": "checked", "command": command})
    training = manager.start(train)
    deadline = time.monotonic() + START_WAIT_SECONDS
    while True:
        row = manager.row(training)
        if row["runs"] or row["state"] != TrainingState.RUNNING or time.monotonic() > deadline:
            break
        await asyncio.sleep(0.05)
        await asyncio.to_thread(manager.tick)
    return {
        "name": row["name"],
        "runs": row["runs"],
        "state": row["state"],
        "command": shown(request, row["command"]),
    }


@router.get("/trainings", response_model=list[TrainingRow])
def list_trainings(
    request: Request,
    run: Annotated[str | None, Query(max_length=MAX_TEXT, description="only the one of this run")] = None,
) -> list[dict[str, Any]]:
    """The trainings started from this app (also by an earlier server on this runs folder), newest first."""
    manager: Trainings | None = request.app.state.trainings
    rows = [] if manager is None else manager.rows()
    return [shown(request, row) for row in rows if run is None or run in row["runs"]]


def act(request: Request, name: str, action: str) -> dict[str, Any]:
    manager = trainings(request)
    try:
        training = manager.stop(name) if action == "stop" else manager.resume(name)
    except TrainingError as err:
        raise HTTPException(404 if err.missing else 409, str(err)) from err
    return shown(request, manager.row(training))


CONFLICT: dict[int | str, dict[str, Any]] = {
    404: {"description": "no such training"},
    409: {"description": "not in a state to do that (stop a running or queued one; resume a stopped one)"},
}


@router.post("/trainings/{name}/stop", response_model=TrainingRow, responses=CONFLICT)
def stop_training(request: Request, name: Name) -> dict[str, Any]:
    """Stop a training: it saves ``latest.pt`` (as Ctrl-C does) and can be resumed; a queued one
    leaves the queue."""
    return act(request, name, "stop")


@router.post("/trainings/{name}/resume", response_model=TrainingRow, responses=CONFLICT)
def resume_training(request: Request, name: Name) -> dict[str, Any]:
    """Resume a stopped training from its runs' ``latest.pt`` (``cartpole train --resume``), or queue it."""
    return act(request, name, "resume")


class SettingOut(BaseModel):
    name: str
    value: Any
    kind: str = Field(description="bool, int, float, str or list; with |none when it may be none")
    doc: str = Field(description="the setting's one-line doc")


class PresetOut(BaseModel):
    name: str
    description: str
    for_images: bool


class AgentOut(BaseModel):
    name: str
    presets: list[PresetOut]


class TrainingOptions(BaseModel):
    envs: list[str]
    agents: list[AgentOut]
    agent: str
    env_id: str
    preset: str = Field(description="the preset shown: the one asked for, else the env's")
    settings: list[SettingOut]
    budget: str = Field(description="the preset's budget")
    max_trainings: int | None
    read_only: bool


@router.get("/training-options", response_model=TrainingOptions, responses=BAD)
def training_options(
    request: Request,
    agent: Annotated[str, Query(max_length=MAX_TEXT)] = DEFAULT_AGENT,
    env_id: Annotated[str, Query(max_length=MAX_TEXT)] = DEFAULT_ENV,
    preset: Annotated[str | None, Query(max_length=MAX_TEXT)] = None,
) -> Any:
    """What the training form offers: the envs, the agents with their presets, and every setting of
    the chosen preset with its value and doc."""
    try:
        to_request(TrainingIn(agent=agent, env_id=env_id, preset=preset, dry_run=True), "runs")
        form = preset_settings(agent, env_id, preset)
    except InputError as err:
        return bad_request(err)
    manager: Trainings | None = request.app.state.trainings
    return {
        "envs": list(OFFERED_ENVS),
        "agents": [{"name": name, "presets": presets_of(name)} for name in agent_names()],
        "agent": agent,
        "env_id": env_id,
        "preset": form.preset,
        "settings": [vars(s) for s in form.settings],
        "budget": form.budget,
        "max_trainings": None if manager is None else manager.max_running,
        "read_only": manager is None,
    }


def check_json_types(request: TrainRequest) -> None:
    """InputError (tagged with the setting) for a setting whose JSON value is not of the setting's own
    type, though ``cartpole train`` would read it from text: an integer setting takes a JSON integer
    (not ``64.0``, ``"64"``), a number setting a JSON number (an integer too: floats stay floats), a
    list of integers JSON integers, a switch ``true`` or ``false``, a nullable setting ``null`` (not
    ``"none"``). Called once the request passed ``cartpole train``'s checks, so that a value those
    refuse gets their message, word for word."""
    spec = get_agent(request.agent)
    hints = {**_field_types(spec.config_cls), **_field_types(TrainSettings)}
    for name, value in request.settings.items():
        hint = hints.get(name)
        if hint is not None and not _fits(value, hint):
            error = ConfigError(f"{name} must be {_kind(hint)}, got {shown_value(value)}")
            error.field = name
            raise error


def _field_types(cls: type) -> dict[str, Any]:
    names = {f.name for f in fields(cls)}
    return {name: hint for name, hint in typing.get_type_hints(cls).items() if name in names}


def _options(hint: Any) -> tuple[Any, ...]:
    union = isinstance(hint, types.UnionType) or typing.get_origin(hint) is typing.Union
    return typing.get_args(hint) if union else (hint,)


def _items(hint: Any) -> tuple[Any, ...] | None:
    """A list's or tuple's item types (``(int, ...)`` for ``tuple[int, ...]``); None if not one."""
    if typing.get_origin(hint) not in (list, tuple):
        return None
    return typing.get_args(hint) or (Any, ...)


def _fits(value: Any, hint: Any) -> bool:
    """Whether a JSON value has the JSON type of a field typed ``hint``."""
    if len(options := _options(hint)) > 1:
        return any(_fits(value, option) for option in options)
    if hint is Any:
        return True
    if hint is type(None):
        return value is None
    if hint is bool:
        return isinstance(value, bool)
    if hint is int:
        return isinstance(value, int) and not isinstance(value, bool)
    if hint is float:
        return isinstance(value, int | float) and not isinstance(value, bool)
    if hint is str:
        return isinstance(value, str)
    if (items := _items(hint)) is not None:
        if not isinstance(value, list):
            return False
        if len(items) == 2 and items[1] is Ellipsis:
            return all(_fits(item, items[0]) for item in value)
        return len(value) == len(items) and all(_fits(v, h) for v, h in zip(value, items, strict=True))
    if typing.get_origin(hint) is dict or hint is dict:
        return isinstance(value, dict)
    return True


KINDS: Mapping[Any, tuple[str, str]] = {
    bool: ("true or false", "switches"),
    int: ("an integer", "integers"),
    float: ("a number", "numbers"),
    str: ("text", "texts"),
    type(None): ("null", "nulls"),
}


def _kind(hint: Any, plural: bool = False) -> str:
    """What a field typed ``hint`` takes, in words: ``an integer``, ``a list of integers``."""
    if len(options := _options(hint)) > 1:
        return " or ".join(_kind(option, plural) for option in options)
    if hint in KINDS:
        return KINDS[hint][plural]
    if (items := _items(hint)) is not None:
        if len(items) == 2 and items[1] is Ellipsis:
            inner = f"of {_kind(items[0], plural=True)}"
        else:
            inner = f"of {len(items)} {_kind(items[0], plural=True)}"
        return f"lists {inner}" if plural else f"a list {inner}"
    return "values" if plural else "a value of its type"


def presets_of(agent: str) -> list[dict[str, Any]]:
    images = image_presets(agent)
    return [
        {"name": name, "description": str(values.get("description", "")), "for_images": name in images}
        for name, values in preset_table(agent).items()
    ]


def default_max_trainings() -> int:
    """``--max-trainings``' default: the cores this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1
