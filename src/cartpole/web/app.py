"""The web app: FastAPI serving the JSON API, the WebSockets and the static pages.

Pages are plain HTML/CSS/JS under ``static/`` (no build step, nothing fetched from the internet);
charts use uPlot, vendored in ``static/vendor`` with its license. The app reads the runs folder; the
trainings it starts (``trainings.py``) write their run folders as ``cartpole train`` does, each in a
process of its own.
"""

from __future__ import annotations

import gc
import threading
from collections.abc import AsyncIterator, Callable, Iterable
from contextlib import asynccontextmanager
from pathlib import Path

from fastapi import FastAPI
from fastapi.responses import FileResponse
from fastapi.staticfiles import StaticFiles

from cartpole.core.version import __version__
from cartpole.web import api, experiments_api, live, trainings_api
from cartpole.web.answers import install_handlers
from cartpole.web.episodes import EpisodeWorkers
from cartpole.web.experiments_folder import ExperimentsFolder
from cartpole.web.replay import Replays
from cartpole.web.runs_folder import RunsFolder
from cartpole.web.security import (
    OwnHosts,
    SameOriginWebSockets,
    SecurityHeaders,
    TokenGate,
    URLLengthLimit,
    allowed_hosts,
    new_token,
)
from cartpole.web.trainings import Trainings
from cartpole.web.trainings_api import default_max_trainings

STATIC = Path(__file__).parent / "static"
PAGES = {
    "/": "runs.html",
    "/run": "run.html",
    "/watch": "watch.html",
    "/play": "play.html",
    "/experiments": "experiments.html",
    "/experiment": "experiment.html",
    "/sweep": "sweep.html",
    "/train": "train.html",
}


def create_app(
    runs_dir: Path | str = "runs",
    allow_hosts: Iterable[str] = (),
    *,
    token: str | None = None,
    read_only: bool = False,
    max_trainings: int | None = None,
    reads_need_token: bool = False,
) -> FastAPI:
    """The app for one runs folder (which need not exist yet: runs made later are noticed).

    It answers only requests addressed to this machine (127.0.0.1, localhost, [::1]) or to one of
    ``allow_hosts`` (the address it is bound to, names given with ``--allow-host``), see security.py.
    Starting, stopping and resuming trainings needs ``token`` (None: a new random one, in
    ``app.state.token``); ``read_only`` refuses every change; ``reads_need_token`` asks the token of
    every request. At most ``max_trainings`` train at once (None: one per core).

    A request names envs only from the app's own list (``envs.py``: nothing it names is imported);
    answers name no path of this machine, and every refusal is ``{"detail": one line, "field"}``
    (``answers.py``).
    """
    # /docs and /redoc would load Swagger UI from a CDN; the schema itself is served at /openapi.json.
    app = FastAPI(
        title="cartpole web",
        version=__version__,
        description="Watch agents, follow training live, play CartPole yourself.",
        docs_url=None,
        redoc_url=None,
        lifespan=_warm_up,
    )
    app.state.runs = RunsFolder(Path(runs_dir))
    app.state.experiments = ExperimentsFolder(Path(runs_dir))
    app.state.episodes = EpisodeWorkers.shared()
    app.state.replays = Replays()
    app.state.token = token or new_token()
    app.state.trainings = (
        None if read_only else Trainings(Path(runs_dir), max_trainings or default_max_trainings())
    )
    install_handlers(app)  # every refusal {"detail": one line, "field"}, naming no path of this machine
    # Outermost last: headers on every answer, then the URL size, the Host, the WebSocket Origin, the token.
    app.add_middleware(
        TokenGate, token=app.state.token, read_only=read_only, reads_need_token=reads_need_token
    )
    app.add_middleware(SameOriginWebSockets)
    app.add_middleware(OwnHosts, allowed_hosts=allowed_hosts(allow_hosts))
    app.add_middleware(URLLengthLimit)
    app.add_middleware(SecurityHeaders)
    app.include_router(api.router)
    app.include_router(experiments_api.router)
    app.include_router(live.router)
    app.include_router(trainings_api.router)
    app.mount("/static", StaticFiles(directory=STATIC), name="static")
    for route, page in PAGES.items():
        app.add_api_route(route, _page(page), include_in_schema=False, methods=["GET"])
    return app


@asynccontextmanager
async def _warm_up(app: FastAPI) -> AsyncIterator[None]:
    """Load the agents' modules and the simulator's compiled kernels in the background at start, so
    the first Watch or Play request does not wait seconds for imports and numba's cache."""
    threading.Thread(target=_load_heavy_modules, name="cartpole-web-warm-up", daemon=True).start()
    app.state.episodes.start()
    trainings: Trainings | None = app.state.trainings
    if trainings is not None:
        trainings.open()
    try:
        yield
    finally:
        if trainings is not None:
            trainings.close()  # each one saves, as after Ctrl-C; Resume goes on after a restart


def _load_heavy_modules() -> None:
    from cartpole.agents.registry import agents
    from cartpole.web.physics import CartPoleSim, start_state

    agents()
    sim = CartPoleSim("CartPole-v1")
    sim.reset(start_state("CartPole-v1", 0))
    sim.step(0)
    _freeze_long_lived_objects()


def _freeze_long_lived_objects() -> None:
    """Keep the cyclic garbage collector off the objects alive after start-up (torch, numba, ...).

    Requests make and drop many small lists; every so often they set off a full collection, which
    otherwise walks these hundreds of thousands of objects for tens of ms, in the middle of a
    request. Frozen objects are still freed by reference counting; garbage is collected first, so
    none is kept for good.
    """
    gc.collect()
    gc.freeze()


def _page(name: str) -> Callable[[], FileResponse]:
    path = STATIC / name

    def page() -> FileResponse:
        return FileResponse(path, headers={"Cache-Control": "no-cache"})

    page.__name__ = f"page_{name.split('.')[0]}"
    return page
