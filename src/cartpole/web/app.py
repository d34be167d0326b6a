"""The web app: FastAPI serving the JSON API, the WebSockets and the static pages.

Pages are plain HTML/CSS/JS under ``static/`` (no build step, nothing fetched from the internet);
charts use uPlot, vendored in ``static/vendor`` with its license. The app only reads the runs folder.
"""

from __future__ import annotations

import gc
import threading
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from pathlib import Path

from fastapi import FastAPI
from fastapi.responses import FileResponse
from fastapi.staticfiles import StaticFiles

from cartpole.core.version import __version__
from cartpole.web import api, live
from cartpole.web.episodes import PolicyCache
from cartpole.web.runs_folder import RunsFolder

STATIC = Path(__file__).parent / "static"
PAGES = {"/": "runs.html", "/run": "run.html", "/watch": "watch.html", "/play": "play.html"}


def create_app(runs_dir: Path | str = "runs") -> FastAPI:
    """The app for one runs folder (which need not exist yet: runs made later are noticed)."""
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
    app.state.policies = PolicyCache()
    app.include_router(api.router)
    app.include_router(live.router)
    app.mount("/static", StaticFiles(directory=STATIC), name="static")
    for route, page in PAGES.items():
        app.add_api_route(route, _page(page), include_in_schema=False, methods=["GET"])
    return app


@asynccontextmanager
async def _warm_up(app: FastAPI) -> AsyncIterator[None]:
    """Load the agents' modules and the simulator's compiled kernels in the background at start, so
    the first Watch or Play request does not wait seconds for imports and numba's cache."""
    threading.Thread(target=_load_heavy_modules, name="cartpole-web-warm-up", daemon=True).start()
    yield


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
