"""The JSON API: runs, one run, its metrics, and episodes of its checkpoints (see /openapi.json)."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, HTTPException, Query, Request
from fastapi.responses import JSONResponse
from pydantic import BaseModel, Field

from cartpole.agents.registry import get_agent
from cartpole.core.names import RunState
from cartpole.core.version import __version__
from cartpole.envs import env_info
from cartpole.runs import CheckpointError, RunDir
from cartpole.web.episodes import MAX_NUDGE, UNLIMITED_STEPS, PolicyCache, play_episode, sim_limits
from cartpole.web.physics import PHYSICS_LABELS, PHYSICS_LIMITS, PhysicsError, default_physics, is_cartpole
from cartpole.web.runs_folder import NotFound, RunsFolder

router = APIRouter(prefix="/api")

MAX_SEED = 2**53
"""Seeds stay exact in JavaScript numbers."""


class RunRow(BaseModel):
    """One row of the runs table."""

    name: str
    agent: str | None
    env_id: str | None
    seed: int | None
    preset: str | None
    created: str | None
    state: str = Field(description=f"one of: {', '.join(RunState)} (crashed: its process is gone)")
    env_steps: int | None
    episodes: int | None
    best_eval_mean: float | None
    solved: bool
    verdict: str | None
    rule: str | None = Field(description='e.g. "mean 498.2 >= 475 over 100 episodes, CartPole-v1"')
    problem: str | None
    watchable: bool = Field(description="CartPole run: its checkpoints can be watched")


class RunsOut(BaseModel):
    runs_dir: str
    runs: list[RunRow]


class MetricsOut(BaseModel):
    offset: int = Field(description="the row the list starts at")
    next_offset: int = Field(description="pass this as offset to fetch only newer rows")
    rows: list[dict[str, Any]]


class EpisodeOut(BaseModel):
    """One greedy episode: ``states`` has length+1 rows (x, x_dot, theta, theta_dot)."""

    run: str
    checkpoint: str
    agent: str | None
    env_id: str
    seed: int
    physics: dict[str, float]
    nudges: list[dict[str, float]]
    length: int
    return_: float = Field(alias="return")
    terminated: bool
    truncated: bool
    states: list[list[float]]
    actions: list[int]
    rewards: list[float]
    scores: list[list[float]] | None = Field(description="Q-values, or the linear [-s, s], per step")
    score_label: str | None
    limits: dict[str, float]


def folder(request: Request) -> RunsFolder:
    return request.app.state.runs


def open_run(request: Request, name: str) -> RunDir:
    try:
        return folder(request).run(name)
    except NotFound as err:
        raise HTTPException(404, str(err)) from err


@router.get("/info")
def info(request: Request) -> dict[str, Any]:
    """Version, the runs folder, and the physics a page may change (defaults and ranges)."""
    return {
        "version": __version__,
        "runs_dir": str(folder(request).root),
        "physics": {
            "defaults": default_physics(),
            "limits": PHYSICS_LIMITS,
            "labels": PHYSICS_LABELS,
        },
        "max_nudge": MAX_NUDGE,
    }


@router.get("/runs", response_model=RunsOut)
def runs(request: Request) -> dict[str, Any]:
    """Every run folder, newest first; half-written or corrupt ones are listed with their problem."""
    return {"runs_dir": str(folder(request).root), "runs": folder(request).summaries()}


@router.get("/runs/{name}")
def run_detail(request: Request, name: str) -> dict[str, Any]:
    """One run: summary, config, status, evaluation report, checkpoints, env threshold."""
    return folder(request).detail(open_run(request, name))


@router.get("/runs/{name}/metrics", response_model=MetricsOut)
def metrics(
    request: Request,
    name: str,
    offset: Annotated[int, Query(ge=0, le=10**9, description="skip this many rows")] = 0,
) -> dict[str, Any]:
    """Metric rows from ``offset`` on (complete lines only: a line being written is left out)."""
    rows, next_offset = open_run(request, name).read_metrics(offset)
    return {"offset": offset, "next_offset": next_offset, "rows": rows}


def physics_query(name: str) -> Any:
    """The query parameter of one physics override, with its limits and label."""
    low, high = PHYSICS_LIMITS[name]
    return Query(ge=low, le=high, description=PHYSICS_LABELS[name])


def nudges_from_query(steps: list[int], changes: list[float], max_steps: int) -> dict[int, float]:
    if len(steps) != len(changes):
        raise HTTPException(422, "give one nudge value per nudge_at step (same count of each)")
    nudges: dict[int, float] = {}
    for step, change in zip(steps, changes, strict=True):
        if not 0 <= step < max_steps:
            raise HTTPException(422, f"nudge_at must be between 0 and {max_steps - 1}, got {step}")
        if not -MAX_NUDGE <= change <= MAX_NUDGE:
            raise HTTPException(422, f"nudge must be between -{MAX_NUDGE:g} and {MAX_NUDGE:g}, got {change}")
        nudges[step] = nudges.get(step, 0.0) + change
    return nudges


NudgeSteps = Annotated[list[int] | None, Query(description="steps before which the pole is pushed")]
NudgeChanges = Annotated[list[float] | None, Query(description="rad/s added to the pole's angular velocity")]


@router.get(
    "/runs/{name}/checkpoints/{checkpoint}/episode",
    response_model=EpisodeOut,
    responses={404: {"description": "no such run or checkpoint"}, 409: {"description": "not CartPole"}},
)
def episode(
    request: Request,
    name: str,
    checkpoint: str,
    seed: Annotated[int, Query(ge=0, le=MAX_SEED, description="start state = Gymnasium reset(seed)")] = 0,
    gravity: Annotated[float | None, physics_query("gravity")] = None,
    length: Annotated[float | None, physics_query("length")] = None,
    masspole: Annotated[float | None, physics_query("masspole")] = None,
    masscart: Annotated[float | None, physics_query("masscart")] = None,
    force_mag: Annotated[float | None, physics_query("force_mag")] = None,
    nudge_at: NudgeSteps = None,
    nudge: NudgeChanges = None,
) -> JSONResponse:
    """The greedy episode of a checkpoint from a seed's start state, with optional physics and nudges."""
    run = open_run(request, name)
    try:
        path = folder(request).checkpoint(run, checkpoint)
    except NotFound as err:
        raise HTTPException(404, str(err)) from err
    env_id, agent = run_env(run)
    if not is_cartpole(env_id):
        raise HTTPException(409, f"{env_id} is not CartPole: only CartPole runs can be watched")
    given = {"gravity": gravity, "length": length, "masspole": masspole, "masscart": masscart}
    overrides = {k: v for k, v in {**given, "force_mag": force_mag}.items() if v is not None}
    max_steps = max_episode_steps(env_id)
    nudges = nudges_from_query(nudge_at or [], nudge or [], max_steps)
    cache: PolicyCache = request.app.state.policies
    try:
        policy = cache.get(path)
        result, sim = play_episode(policy, env_id, seed, overrides, nudges)
    except CheckpointError as err:
        raise HTTPException(409, f"checkpoint {checkpoint} cannot be loaded: {err}") from err
    except PhysicsError as err:
        raise HTTPException(422, str(err)) from err
    label = score_label(agent)
    body = {
        "run": run.name,
        "checkpoint": checkpoint,
        "agent": agent,
        **result.to_dict(sim_limits(sim), label),
    }
    return JSONResponse(body)


def score_label(agent: str | None) -> str:
    """What the agent's per-action scores mean, as the agent itself says."""
    try:
        return get_agent(str(agent)).score_label
    except ValueError:  # an agent this version does not know
        return "score"


def run_env(run: RunDir) -> tuple[str, str | None]:
    """(env id, agent) from a run's config; 409 if the config cannot be read."""
    try:
        config = run.config()
    except ValueError as err:
        raise HTTPException(409, f"run {run.name} has no readable config: {err}") from err
    env_id = config.get("env_id")
    if not isinstance(env_id, str):
        raise HTTPException(409, f"run {run.name} records no env_id")
    return env_id, config.get("agent")


def max_episode_steps(env_id: str) -> int:
    return env_info(env_id).max_episode_steps or UNLIMITED_STEPS
