"""The JSON API that starts, stops and resumes trainings (``web/trainings.py``), see /openapi.json.

Every POST here needs the server's token and the page's own origin (``security.TokenGate``). What a
request may name comes from the app's own lists: an env of :data:`TRAINABLE_ENVS`, an agent, one of
its named presets (never a file), settings of that preset (never an import path); the checks and
their messages are ``cartpole train``'s (:func:`cartpole.training.request.check_request`).
"""

from __future__ import annotations

import asyncio
import os
import time
from typing import Annotated, Any

from fastapi import APIRouter, HTTPException, Path, Query, Request
from fastapi.responses import JSONResponse
from pydantic import BaseModel, ConfigDict, Field, StrictBool, StrictFloat, StrictInt, StrictStr

from cartpole.agents.presets import image_presets, preset_table
from cartpole.agents.registry import DEFAULT_AGENT, agent_names
from cartpole.core.errors import ConfigError, InputError
from cartpole.training.request import (
    DEFAULT_ENV,
    MAX_SEEDS,
    TrainRequest,
    about,
    check_request,
    preset_settings,
    train_command,
)
from cartpole.web.trainings import TrainingError, Trainings, TrainingState

router = APIRouter(prefix="/api")

TRAINABLE_ENVS = (
    "CartPole-v1",
    "CartPole-v0",
    "Acrobot-v1",
    "MountainCar-v0",
    "cartpole/CartPolePixels-v1",
)
"""The envs a training started from the web app may use (the app lists them; nothing else is made)."""
START_WAIT_SECONDS = 30.0
"""How long a start waits for its process to name its run folders before it answers without them."""
MAX_SETTINGS = 200
MAX_TEXT = 200

JSONValue = (
    StrictBool | StrictInt | StrictFloat | Annotated[StrictStr, Field(max_length=MAX_TEXT)] | list[Any] | None
)


class TrainingIn(BaseModel):
    """A training to start: what ``cartpole train`` takes, as JSON."""

    model_config = ConfigDict(extra="forbid")

    agent: Annotated[str, Field(max_length=MAX_TEXT, description="an agent, as `cartpole train AGENT`")]
    env_id: Annotated[
        str | None, Field(max_length=MAX_TEXT, description=f"one of {', '.join(TRAINABLE_ENVS)}")
    ] = None
    preset: Annotated[
        str | None, Field(max_length=MAX_TEXT, description="a named preset of the agent (default: the env's)")
    ] = None
    seeds: Annotated[
        list[int] | None,
        Field(
            max_length=MAX_SEEDS, description="training seeds; one: a run; several: a population (--seeds)"
        ),
    ] = None
    budget: Annotated[
        str | None, Field(max_length=MAX_TEXT, description="as --budget takes it: 50k, 300ep, 20gen, 90s")
    ] = None
    settings: Annotated[
        dict[str, JSONValue],
        Field(max_length=MAX_SETTINGS, description="setting name -> value, as --set KEY=VALUE would give it"),
    ] = {}
    dry_run: bool = Field(False, description="check only: start nothing, answer with the command")


class TrainingRow(BaseModel):
    name: str
    state: TrainingState
    runs: list[str] = Field(description="its run folders' names ([] until its process has made them)")
    agent: str | None = None
    env_id: str | None = None
    seeds: list[int] | None = None
    created: str | None = None
    command: list[str] = Field(default_factory=list, description="the `cartpole train` command it runs")
    request: dict[str, Any] = Field(default_factory=dict)
    problem: str | None = Field(None, description="why it failed, in one line")
    queue_position: int | None = Field(None, description="1: the next to start")


class TrainingStarted(BaseModel):
    name: str | None = Field(description="the training's name (null for a dry run)")
    runs: list[str]
    state: str = Field(description="queued or running (checked, for a dry run)")
    command: list[str]


class BadRequest(BaseModel):
    detail: str = Field(description="what is wrong, in one line (as `cartpole train` says it)")
    field: str | None = Field(
        description="the input it is about: agent, env_id, preset, seeds, budget or a setting"
    )


BAD: dict[int | str, dict[str, Any]] = {
    422: {"model": BadRequest, "description": "a bad request; nothing started"}
}
Name = Annotated[str, Path(max_length=MAX_TEXT)]


def trainings(request: Request) -> Trainings:
    found: Trainings | None = request.app.state.trainings
    if found is None:
        raise HTTPException(403, "this server is read-only (cartpole serve --read-only): it starts nothing")
    return found


def bad_request(err: InputError) -> JSONResponse:
    return JSONResponse({"detail": " ".join(str(err).split()), "field": err.field}, status_code=422)


def to_request(body: TrainingIn, runs_dir: str) -> TrainRequest:
    """The request, or InputError for what the app does not offer (another env, a preset file)."""
    env_id = body.env_id or DEFAULT_ENV
    with about("env_id"):
        if env_id not in TRAINABLE_ENVS:
            raise ConfigError(
                f"env {env_id!r} is not one the web app trains: choose one of {', '.join(TRAINABLE_ENVS)} "
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
    except InputError as err:
        return bad_request(err)
    if manager is None:
        return JSONResponse({"name": None, "runs": [], "state": "checked", "command": train_command(train)})
    training = manager.start(train)
    deadline = time.monotonic() + START_WAIT_SECONDS
    while True:
        row = manager.row(training)
        if row["runs"] or row["state"] != TrainingState.RUNNING or time.monotonic() > deadline:
            break
        await asyncio.sleep(0.05)
        await asyncio.to_thread(manager.tick)
    return {"name": row["name"], "runs": row["runs"], "state": row["state"], "command": row["command"]}


@router.get("/trainings", response_model=list[TrainingRow])
def list_trainings(
    request: Request,
    run: Annotated[str | None, Query(max_length=MAX_TEXT, description="only the one of this run")] = None,
) -> list[dict[str, Any]]:
    """The trainings started from this app (also by an earlier server on this runs folder), newest first."""
    manager: Trainings | None = request.app.state.trainings
    rows = [] if manager is None else manager.rows()
    return [row for row in rows if run is None or run in row["runs"]]


def act(request: Request, name: str, action: str) -> dict[str, Any]:
    manager = trainings(request)
    try:
        training = manager.stop(name) if action == "stop" else manager.resume(name)
    except TrainingError as err:
        raise HTTPException(404 if err.missing else 409, str(err)) from err
    return manager.row(training)


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
        "envs": list(TRAINABLE_ENVS),
        "agents": [{"name": name, "presets": presets_of(name)} for name in agent_names()],
        "agent": agent,
        "env_id": env_id,
        "preset": form.preset,
        "settings": [vars(s) for s in form.settings],
        "budget": form.budget,
        "max_trainings": None if manager is None else manager.max_running,
        "read_only": manager is None,
    }


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
