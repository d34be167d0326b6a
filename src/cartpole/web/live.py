"""WebSockets: a running training's metrics as they are appended, and play sessions.

Metrics (``/ws/runs/{name}/metrics?offset=N``): the server sends ``{"type": "metrics", "offset",
"rows"}`` whenever ``metrics.jsonl`` grows and ``{"type": "status", "status"}`` whenever
``status.json`` changes or the displayed state does (``status.state`` is
:func:`~cartpole.runs.displayed_state`: a run whose process died shows "crashed"); once the run has
stopped and every row is sent it sends ``{"type": "end", "state"}`` and closes. The client sends
nothing (anything it sends closes the socket with a reason).

Play (``/ws/play?env=CartPole-v1``): one simulated cart-pole per connection, on an env of the app's
own list (:data:`~cartpole.web.envs.OFFERED_ENVS`; any other closes the socket with code 1008 and a
reason before anything looks it up, so nothing a request names is imported). Client messages:
``{"type": "reset", "seed"?: int, "physics"?: {...}}``, ``{"type": "step", "action": 0|1}``;
each is answered by ``{"type": "state", "seed", "step", "state": [x, x_dot, theta, theta_dot],
"reward", "return", "terminated", "truncated"}``. The pace of steps is the client's (that is how
slow motion works); physics always runs here. Messages are checked strictly (an action is the
JSON integer 0 or 1, not ``1.0`` or ``true``; no unknown fields). A message of an unknown type is
answered by ``{"type": "error", "message"}``; one that is malformed closes the socket with code
1008 and a reason, and one longer than ``MAX_PLAY_MESSAGE`` bytes with code 1009. Other
connections are not affected.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import random
from pathlib import Path
from typing import Annotated, Any, Literal

from fastapi import APIRouter, Query, WebSocket, WebSocketDisconnect
from pydantic import BaseModel, ConfigDict, Field, TypeAdapter, ValidationError

from cartpole.core.names import RunState
from cartpole.runs import RunDir, displayed_state
from cartpole.runs.run_dir import STOPPED_STATES
from cartpole.web.answers import MAX_CLOSE_REASON, POLICY_VIOLATION, close_reason, shown_paths
from cartpole.web.api import MAX_SEED
from cartpole.web.envs import OFFERED_ENVS, offered, shown_env
from cartpole.web.episodes import sim_limits
from cartpole.web.physics import (
    ACTION_LABELS,
    CartPoleSim,
    GymSim,
    PhysicsError,
    scene_of,
    start_state,
)
from cartpole.web.runs_folder import NotFound, RunsFolder

router = APIRouter()

POLL_SECONDS = 0.4
MESSAGE_TOO_BIG = 1009
MAX_PLAY_MESSAGE = 4096
"""Longest play message, in bytes (a reset with every physics setting is about 150)."""


# ---------------------------------------------------------------------------------------------------
# Live metrics
# ---------------------------------------------------------------------------------------------------


def _stamp(path: Path) -> tuple[int, int] | None:
    try:
        stat = path.stat()
    except OSError:
        return None
    return stat.st_size, stat.st_mtime_ns


@router.websocket("/ws/runs/{name}/metrics")
async def live_metrics(websocket: WebSocket, name: str, offset: int = 0) -> None:
    """Push new metric rows and status changes of a run until it stops."""
    folder: RunsFolder = websocket.app.state.runs
    try:
        run = folder.run(name)
    except NotFound as err:
        await websocket.close(code=POLICY_VIOLATION, reason=str(err)[:120])
        return
    await websocket.accept()
    offset = max(0, offset)
    reader = asyncio.ensure_future(receive_text(websocket))
    try:
        await _follow(websocket, run, offset, reader)
    except WebSocketDisconnect:
        pass
    finally:
        reader.cancel()


async def _follow(websocket: WebSocket, run: RunDir, offset: int, reader: asyncio.Future[str | None]) -> None:
    seen_metrics = seen_status = None
    state = shown = RunState.UNKNOWN
    while True:
        stamp = _stamp(run.path / "status.json")
        status = None
        changed = stamp != seen_status
        if changed or state is RunState.RUNNING:  # a running run can crash with nothing written
            seen_status, status = stamp, run.status()
            state = displayed_state(status)
            if changed or state is not shown:
                shown = state
                message = shown_paths({**status, "state": state.value}, websocket.app.state.runs.root)
                await websocket.send_json({"type": "status", "status": message})
        stamp = _stamp(run.metrics_path)
        if stamp != seen_metrics:
            seen_metrics = stamp
            rows, next_offset = await asyncio.to_thread(run.read_metrics, offset)
            if rows:
                await websocket.send_json({"type": "metrics", "offset": offset, "rows": rows})
            offset = next_offset
        if status is not None and state in STOPPED_STATES and stamp == _stamp(run.metrics_path):
            await websocket.send_json({"type": "end", "state": state.value})
            await websocket.close(code=1000, reason="run stopped")
            return
        done, _ = await asyncio.wait({reader}, timeout=POLL_SECONDS)
        if done:
            reader.result()  # raises WebSocketDisconnect if the client left
            await websocket.close(code=POLICY_VIOLATION, reason="this socket only sends; send nothing")
            return


# ---------------------------------------------------------------------------------------------------
# Play
# ---------------------------------------------------------------------------------------------------


class Reset(BaseModel):
    model_config = ConfigDict(strict=True, extra="forbid")
    type: Literal["reset"]
    seed: int | None = Field(default=None, ge=0, le=MAX_SEED)
    physics: dict[str, float] | None = Field(default=None, max_length=16)


class Step(BaseModel):
    model_config = ConfigDict(strict=True, extra="forbid")
    type: Literal["step"]
    action: int = Field(
        ge=0,
        le=2,
        description="CartPole: 0 pushes the cart left, 1 right; Acrobot and MountainCar: 0, 1 or 2",
    )


PLAY_TYPES = ("reset", "step")
PlayMessage: TypeAdapter[Reset | Step] = TypeAdapter(Annotated[Reset | Step, Field(discriminator="type")])


class PlaySession:
    """One human's game: a server-side env (our cart-pole, or Gymnasium's Acrobot or MountainCar)
    and the running score."""

    def __init__(self, env_id: str):
        self.scene = scene_of(env_id) or "cartpole"
        self.sim: CartPoleSim | GymSim = CartPoleSim(env_id) if self.scene == "cartpole" else GymSim(env_id)
        self.seed: int | None = None
        self.total = 0.0

    def handle(self, message: Reset | Step) -> dict[str, Any]:
        if isinstance(message, Reset):
            return self.reset(message)
        if self.seed is None or self.sim.done:
            raise PhysicsError("no episode in progress: send a reset first")
        result = self.sim.step(message.action)
        self.total += result.reward
        return self.reply(result.reward, result.terminated, result.truncated)

    def reset(self, message: Reset) -> dict[str, Any]:
        sim = self.sim
        if message.physics and not isinstance(sim, CartPoleSim):
            raise PhysicsError(f"physics changes CartPole only; {sim.env_id} plays as Gymnasium has it")
        self.seed = random.randrange(2**31) if message.seed is None else message.seed
        self.total = 0.0
        if isinstance(sim, CartPoleSim):
            if message.physics is not None:
                sim.set_physics(message.physics)
            sim.reset(start_state(sim.env_id, self.seed))
            scene = {"physics": sim.physics(), "limits": sim_limits(sim)}
        else:
            sim.reset(self.seed)
            scene = {"physics": {}, "limits": sim.limits()}
        labels = ACTION_LABELS[self.scene]
        return {**self.reply(0.0, False, False), **scene, "scene": self.scene, "action_labels": labels}

    def reply(self, reward: float, terminated: bool, truncated: bool) -> dict[str, Any]:
        return {
            "type": "state",
            "seed": self.seed,
            "step": self.sim.steps,
            "state": self.sim.state.tolist(),
            "reward": reward,
            "return": self.total,
            "terminated": terminated,
            "truncated": truncated,
        }


@router.websocket("/ws/play")
async def play(
    websocket: WebSocket,
    env: Annotated[str, Query(max_length=64)] = "CartPole-v1",
) -> None:
    """A live game: reset, then one step message per action; every reply is the new state. ``env`` is
    one of the app's own (:data:`~cartpole.web.envs.OFFERED_ENVS`), checked before anything looks it
    up: any other closes the socket with a reason, and nothing it names is imported."""
    if not offered(env) or scene_of(env) is None:
        await websocket.close(code=POLICY_VIOLATION, reason=not_playable(env))
        return
    await websocket.accept()
    session = PlaySession(env)
    with contextlib.suppress(WebSocketDisconnect):
        while True:
            text = await receive_text(websocket)
            if text is not None and len(text.encode()) > MAX_PLAY_MESSAGE:
                reason = f"messages are at most {MAX_PLAY_MESSAGE} bytes"
                await websocket.close(code=MESSAGE_TOO_BIG, reason=reason)
                return
            try:
                reply = session.handle(PlayMessage.validate_json(text or ""))
            except ValidationError as err:
                if _unknown_type(err):
                    await websocket.send_json({"type": "error", "message": _unknown_type_message(text)})
                    continue
                await websocket.close(code=POLICY_VIOLATION, reason=_reason(err))
                return
            except PhysicsError as err:
                await websocket.send_json({"type": "error", "message": str(err)})
                continue
            await websocket.send_text(json.dumps(reply))


def not_playable(env: str) -> str:
    """The close reason for an env that cannot be played (one the app does not offer): the env, cut to
    what a close reason holds beside the envs that can be."""
    playable = f" cannot be played; play {', '.join(OFFERED_ENVS)}"
    limit = len(env)
    while limit > 1 and len((shown_env(env, limit) + playable).encode()) > MAX_CLOSE_REASON:
        limit -= 1
    return close_reason(shown_env(env, limit) + playable)


async def receive_text(websocket: WebSocket) -> str | None:
    """The next text message; None for a binary one; WebSocketDisconnect when the client leaves."""
    message = await websocket.receive()
    if message["type"] == "websocket.disconnect":
        raise WebSocketDisconnect(message.get("code", 1000))
    return message.get("text")


def _unknown_type(err: ValidationError) -> bool:
    """A JSON object whose ``type`` is a string this socket does not know."""
    return any(e["type"] == "union_tag_invalid" for e in err.errors())


def _unknown_type_message(text: str | None) -> str:
    kind = json.loads(text or "{}").get("type")
    return f"unknown message type {str(kind)[:40]!r}: send one of {', '.join(PLAY_TYPES)}"


def _reason(err: ValidationError) -> str:
    """A close reason (at most 123 bytes) saying what was wrong with the message."""
    first = err.errors()[0]
    where = ".".join(str(p) for p in first.get("loc", ())) or "message"
    text = f"bad message ({where}: {first.get('msg', 'invalid')}); see /ws/play in the docs"
    return text.encode()[:120].decode(errors="ignore")
