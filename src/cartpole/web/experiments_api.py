"""The JSON API of experiments (``cartpole compare``) and sweeps (``cartpole sweep``), see /openapi.json.

Sync endpoints: FastAPI runs them in its thread pool, so reading a report or an Optuna journal never
holds up the event loop (play sessions, live metrics).
"""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, HTTPException, Path, Request
from fastapi.responses import FileResponse, PlainTextResponse
from pydantic import BaseModel

from cartpole.web.answers import shown_paths
from cartpole.web.experiments_folder import (
    ExperimentOut,
    ExperimentRow,
    ExperimentsFolder,
    SweepOut,
    SweepRow,
)
from cartpole.web.runs_folder import NotFound

router = APIRouter(prefix="/api")

NOT_FOUND: dict[int | str, dict[str, Any]] = {
    404: {"description": "no such experiment or sweep (or a name that is not allowed)"}
}
Name = Annotated[str, Path(max_length=200, description="the folder's name (letters, digits, '.', '_', '-')")]


class ExperimentsOut(BaseModel):
    experiments: list[ExperimentRow]
    sweeps: list[SweepRow]


def experiments_folder(request: Request) -> ExperimentsFolder:
    return request.app.state.experiments


def _shown(request: Request, value: Any) -> Any:
    return shown_paths(value, request.app.state.runs.root)


@router.get("/experiments", response_model=ExperimentsOut)
def experiments(request: Request) -> dict[str, Any]:
    """Every experiment under ``experiments/`` and every sweep under ``sweeps/`` of the runs folder."""
    folder = experiments_folder(request)
    return _shown(request, {"experiments": folder.experiments(), "sweeps": folder.sweeps()})


@router.get("/experiments/{name}", response_model=ExperimentOut, responses=NOT_FOUND)
def experiment(request: Request, name: Name) -> Any:
    """One experiment: the report (counts, times to solve and final returns with 95% CIs) and figures;
    a report that cannot be read is named in ``problem``."""
    try:
        found = experiments_folder(request).experiment(name)
    except NotFound as err:
        raise HTTPException(404, str(err)) from err
    if found["report"] is not None:
        found["report"] = found["report"].model_dump()
    return _shown(request, found)


@router.get(
    "/experiments/{name}/figures/{figure}.png",
    response_class=FileResponse,
    responses={**NOT_FOUND, 200: {"content": {"image/png": {}}}},
)
def figure(request: Request, name: Name, figure: Annotated[str, Path(max_length=40)]) -> FileResponse:
    """A figure of the experiment: ``curves``, ``solve_steps``, ``performance_profile`` (rliable's
    performance profiles of the final returns) or ``improvement`` (their probability of improvement)."""
    try:
        path = experiments_folder(request).figure(name, figure)
    except NotFound as err:
        raise HTTPException(404, str(err)) from err
    return FileResponse(path, media_type="image/png", headers={"Cache-Control": "no-cache"})


@router.get("/sweeps/{name}", response_model=SweepOut, responses=NOT_FOUND)
def sweep(request: Request, name: Name) -> Any:
    """One sweep: its settings, its trials (values, states, settings) from the Optuna journal, the best
    trial's preset file, and how to open the study in optuna-dashboard."""
    try:
        return _shown(request, experiments_folder(request).sweep(name))
    except NotFound as err:
        raise HTTPException(404, str(err)) from err


@router.get(
    "/sweeps/{name}/best.toml",
    response_class=PlainTextResponse,
    responses={**NOT_FOUND, 200: {"content": {"text/plain": {}}}},
)
def best_toml(request: Request, name: Name) -> PlainTextResponse:
    """The sweep's best trial as a preset file (``cartpole train AGENT --preset best.toml``)."""
    try:
        text = experiments_folder(request).best_toml(name)
    except NotFound as err:
        raise HTTPException(404, str(err)) from err
    return PlainTextResponse(_shown(request, text), headers={"Cache-Control": "no-cache"})
