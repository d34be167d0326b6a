"""The JSON API: runs, one run, its metrics, and episodes of its checkpoints (see /openapi.json)."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, HTTPException, Query, Request
from fastapi.responses import Response
from pydantic import BaseModel, Field

from cartpole.agents.registry import get_agent
from cartpole.core.errors import InputError
from cartpole.core.names import RunState
from cartpole.core.version import __version__
from cartpole.envs import env_info
from cartpole.runs import CheckpointError, RunDir, RunError
from cartpole.web.answers import Refused, shown_paths, shown_root
from cartpole.web.episodes import MAX_NUDGE, UNLIMITED_STEPS, EpisodesBusy, EpisodeWorkers
from cartpole.web.physics import (
    PHYSICS_LABELS,
    PHYSICS_LIMITS,
    SCENES,
    PhysicsError,
    default_physics,
    scene_of,
)
from cartpole.web.replay import ReplayBusy, Replays
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
    state: str = Field(
        description=f"one of: {', '.join(RunState)} (crashed: its process is gone; unreadable: see problem)"
    )
    env_steps: int | None
    episodes: int | None
    best_eval_mean: float | None
    solved: bool
    verdict: str | None
    rule: str | None = Field(description='e.g. "mean 498.2 >= 475 over 100 episodes, CartPole-v1"')
    problem: str | None
    watchable: bool = Field(description="a run on an env Watch draws (CartPole, Acrobot-v1, MountainCar-v0)")
    has_checkpoint: bool = Field(
        default=False, description="it has a checkpoint to watch (a file, not a link)"
    )


class RunsOut(BaseModel):
    runs_dir: str = Field(description="the runs folder as given to `cartpole serve` (its name if absolute)")
    runs: list[RunRow]
    problem: str | None = Field(None, description="why the runs folder itself cannot be listed, if it cannot")


class MetricsOut(BaseModel):
    offset: int = Field(description="the row the list starts at")
    next_offset: int = Field(description="pass this as offset to fetch only newer rows")
    rows: list[dict[str, Any]]


class AgentView(BaseModel):
    """A pixel agent's frames: one per state. The agent's observation at step t is frames
    t-stack+1..t, oldest first, the first frame repeated before step 0 (as the env stacks them)."""

    stack: int = Field(description="frames per observation")
    height: int
    width: int
    frames: list[str] = Field(
        description="each state's frame: base64 of height x width uint8 gray levels, row-major"
    )


class EpisodeOut(BaseModel):
    """One greedy episode: ``states`` has length+1 rows, each the env's own state (CartPole: x, x_dot,
    theta, theta_dot; Acrobot: theta1, theta2 and their speeds; MountainCar: position, velocity)."""

    run: str
    checkpoint: str
    agent: str | None
    env_id: str
    scene: str = Field(description="which drawing shows it: cartpole, acrobot or mountaincar")
    action_labels: list[str] = Field(description="what each action does, in the env's order")
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
    scores: list[list[float]] | None = Field(
        description="the policy's score of each action at each step (what they are: score_label)"
    )
    score_label: str | None
    limits: dict[str, float]
    view: AgentView | None = Field(
        None, description="what a pixel agent saw (runs on cartpole/CartPolePixels-*); null for state agents"
    )


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
        "runs_dir": shown_root(folder(request).root),
        "physics": {
            "defaults": default_physics(),
            "limits": PHYSICS_LIMITS,
            "labels": PHYSICS_LABELS,
        },
        "max_nudge": MAX_NUDGE,
    }


@router.get("/runs", response_model=RunsOut)
def runs(request: Request) -> dict[str, Any]:
    """Every run folder, newest first; half-written or unreadable ones are listed with their problem."""
    runs_folder = folder(request)
    try:
        rows, problem = shown_paths(runs_folder.summaries(), runs_folder.root), None
    except RunError as err:
        rows, problem = [], shown_paths(str(err), runs_folder.root)
    return {"runs_dir": shown_root(runs_folder.root), "runs": rows, "problem": problem}


@router.get("/runs/{name}")
def run_detail(request: Request, name: str) -> dict[str, Any]:
    """One run: summary, config, status, evaluation report, checkpoints, env threshold."""
    runs = folder(request)
    return shown_paths(runs.detail(open_run(request, name)), runs.root)


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
        raise Refused(422, "give one nudge value per nudge_at step (same count of each)", "nudge")
    nudges: dict[int, float] = {}
    for step, change in zip(steps, changes, strict=True):
        if not 0 <= step < max_steps:
            raise Refused(422, f"nudge_at must be between 0 and {max_steps - 1}, got {step}", "nudge_at")
        if not -MAX_NUDGE <= change <= MAX_NUDGE:
            raise Refused(
                422, f"nudge must be between -{MAX_NUDGE:g} and {MAX_NUDGE:g}, got {change}", "nudge"
            )
        nudges[step] = nudges.get(step, 0.0) + change
    return nudges


StartSeed = Annotated[int, Query(ge=0, le=MAX_SEED, description="start state = Gymnasium reset(seed)")]
NudgeSteps = Annotated[list[int] | None, Query(description="steps before which the pole is pushed")]
NudgeChanges = Annotated[list[float] | None, Query(description="rad/s added to the pole's angular velocity")]


@router.get(
    "/runs/{name}/checkpoints/{checkpoint}/episode",
    response_model=EpisodeOut,
    responses={
        404: {"description": "no such run or checkpoint"},
        409: {"description": "an env Watch does not draw, or the checkpoint cannot be loaded"},
        503: {"description": "too many episodes asked for at once: retry"},
    },
)
async def episode(
    request: Request,
    name: str,
    checkpoint: str,
    seed: StartSeed = 0,
    gravity: Annotated[float | None, physics_query("gravity")] = None,
    length: Annotated[float | None, physics_query("length")] = None,
    masspole: Annotated[float | None, physics_query("masspole")] = None,
    masscart: Annotated[float | None, physics_query("masscart")] = None,
    force_mag: Annotated[float | None, physics_query("force_mag")] = None,
    nudge_at: NudgeSteps = None,
    nudge: NudgeChanges = None,
) -> Response:
    """The greedy episode of a checkpoint from a seed's start state, with optional physics and nudges
    (computed in a worker process: the server goes on answering meanwhile)."""
    run = open_run(request, name)
    try:
        path = folder(request).checkpoint(run, checkpoint)
    except NotFound as err:
        raise HTTPException(404, str(err)) from err
    env_id, agent = run_env(run)
    scene = scene_of(env_id)
    if scene is None:
        drawn = ", ".join(["CartPole-v1", "CartPole-v0", *SCENES])
        raise HTTPException(409, f"{env_id} cannot be drawn: Watch shows runs on {drawn}")
    given = {"gravity": gravity, "length": length, "masspole": masspole, "masscart": masscart}
    overrides = {k: v for k, v in {**given, "force_mag": force_mag}.items() if v is not None}
    max_steps = max_episode_steps(env_id)
    nudges = nudges_from_query(nudge_at or [], nudge or [], max_steps)
    if scene != "cartpole" and (overrides or nudges):
        raise HTTPException(
            422, f"physics and nudges change CartPole only; {env_id} plays as Gymnasium has it"
        )
    workers: EpisodeWorkers = request.app.state.episodes
    try:
        header = {"run": run.name, "checkpoint": checkpoint, "agent": agent}
        body = await workers.episode(path, env_id, seed, overrides, nudges, score_label(agent), header)
    except CheckpointError as err:
        raise HTTPException(409, f"checkpoint {checkpoint} cannot be loaded: {err}") from err
    except PhysicsError as err:
        raise HTTPException(422, str(err)) from err
    except EpisodesBusy as err:
        raise HTTPException(503, str(err), headers={"Retry-After": "1"}) from err
    return Response(body, media_type="application/json")


@router.get(
    "/runs/{name}/checkpoints/{checkpoint}/replay.gif",
    response_class=Response,
    responses={
        200: {"content": {"image/gif": {}}, "description": "a GIF of the episode's rgb_array frames"},
        404: {"description": "no such run or checkpoint"},
        409: {"description": "the checkpoint cannot be loaded, or its env draws no frames"},
        503: {"description": "a replay is being made already: retry"},
    },
)
async def replay(
    request: Request,
    name: str,
    checkpoint: str,
    seed: StartSeed = 0,
) -> Response:
    """A GIF of the checkpoint's greedy episode from a seed's start state, from the env's own
    ``rgb_array`` frames (its first steps: REPLAY_STEPS), played as its verdict plays it: for runs on
    envs that Watch does not draw, such as a user's ``module:Id`` env."""
    run = open_run(request, name)
    try:
        path = folder(request).checkpoint(run, checkpoint)
    except NotFound as err:
        raise HTTPException(404, str(err)) from err
    replays: Replays = request.app.state.replays
    try:
        body = await replays.gif(path, seed)
    except (CheckpointError, InputError) as err:
        raise HTTPException(409, f"no replay of {checkpoint}: {err}") from err
    except ReplayBusy as err:
        raise HTTPException(503, str(err), headers={"Retry-After": "1"}) from err
    return Response(body, media_type="image/gif")


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
