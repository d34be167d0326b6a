"""``cartpole serve``: the local web app (runs, live learning curves, watch agents, play yourself)."""

from __future__ import annotations

import argparse
import re
import signal
import socket
from pathlib import Path
from typing import Any

TOKEN_TEXT = re.compile(r"^[A-Za-z0-9._-]{1,200}$")
INSTALL_HINT = "the web app needs FastAPI and uvicorn: pip install fastapi uvicorn websockets"


def add_parser(sub: Any) -> None:
    parser = sub.add_parser(
        "serve",
        help="start the local web app",
        description=(
            "Serve the web app for the runs under --runs-dir: a runs table, live learning curves, "
            "agents played on a canvas, CartPole to play yourself, and a page that trains agents (each "
            "training a `cartpole train` process of its own). It prints its address with its token: "
            "starting, stopping or resuming a training needs the token."
        ),
    )
    parser.add_argument("--runs-dir", default="runs", metavar="DIR", help="(default: runs)")
    parser.add_argument(
        "--host", default="127.0.0.1", help="address to bind (default: 127.0.0.1, this machine only)"
    )
    parser.add_argument("--port", type=int, default=8000, help="(default: 8000)")
    parser.add_argument(
        "--allow-host",
        action="append",
        default=[],
        metavar="NAME",
        help=(
            "also answer requests addressed to NAME (a host name or address this machine is reached by); "
            "repeatable. 127.0.0.1, localhost, [::1] and --host are always allowed; other hosts get 400"
        ),
    )
    parser.add_argument(
        "--token",
        metavar="TOKEN",
        help="the token that starting, stopping and resuming trainings need (default: a new random one, "
        "printed in the address); opening the address sets it as a cookie, programs send "
        "Authorization: Bearer TOKEN",
    )
    parser.add_argument(
        "--read-only",
        action="store_true",
        help="only show runs: refuse every change (no trainings started, stopped or resumed)",
    )
    parser.add_argument(
        "--max-trainings",
        type=int,
        metavar="N",
        help="trainings that run at once; later ones wait in a queue (default: one per core)",
    )
    parser.set_defaults(run=serve)


def serve(args: argparse.Namespace) -> int:
    from cartpole.cli.errors import UsageError

    try:
        import uvicorn

        from cartpole.web.app import create_app
        from cartpole.web.security import SERVER_OPTIONS
    except ImportError as err:
        raise UsageError(f"{INSTALL_HINT} ({err})") from err
    if not 0 < args.port < 65536:
        raise UsageError(f"--port must be between 1 and 65535, got {args.port}")
    if args.token is not None and not args.token.strip():
        raise UsageError(
            "--token is empty: give a token (letters, digits, - and _), or leave it out for a new one"
        )
    if args.token is not None and not TOKEN_TEXT.match(args.token):
        raise UsageError("--token may hold only letters, digits, '-', '_' and '.' (it goes in an address)")
    if args.max_trainings is not None and args.max_trainings < 1:
        raise UsageError(f"--max-trainings must be at least 1, got {args.max_trainings}")
    check_can_listen(args.host, args.port)
    runs_dir = Path(args.runs_dir)
    local = args.host in ("127.0.0.1", "localhost", "::1")
    app = create_app(
        runs_dir,
        allow_hosts=[args.host, *args.allow_host],
        token=args.token,
        read_only=args.read_only,
        max_trainings=args.max_trainings,
        reads_need_token=not local,
    )
    host = f"[{args.host}]" if ":" in args.host else args.host
    address = f"http://{host}:{args.port}/"
    if not args.read_only or not local:
        address += f"?token={app.state.token}"
    print(f"cartpole web app for {runs_dir.resolve()}/ at {address}  (Ctrl+C to stop)", flush=True)
    if args.read_only:
        print("read-only: runs are shown, nothing is started or changed")
    if not local:
        print(
            f"warning: bound to {args.host}: other machines can reach this app; every request needs its token"
        )
    previous = signal.signal(signal.SIGTERM, exit_on_sigterm)
    try:
        uvicorn.run(app, host=args.host, port=args.port, log_level="warning", **SERVER_OPTIONS)
    except OSError as err:
        raise UsageError(f"cannot listen on {args.host}:{args.port}: {err}") from err
    finally:
        signal.signal(signal.SIGTERM, previous)
    return 0


def exit_on_sigterm(signum: int, frame: Any) -> None:
    """After its graceful shutdown uvicorn raises a SIGTERM it caught again, under the handler it
    found: exit through Python's own exit then (status 128 + 15, as a SIGTERM's), which shuts the
    episode workers' pool down and lets multiprocessing release its semaphores, instead of dying at
    once and leaving them to the resource tracker's "leaked semaphore" warning."""
    raise SystemExit(128 + signum)


def check_can_listen(host: str, port: int) -> None:
    """UsageError unless ``host`` is an address of this machine and ``port`` is free on it: one line
    now, instead of the server's own log lines and exit code 1 or 3 later."""
    from cartpole.cli.errors import UsageError

    try:
        family, kind, proto, _, address = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0]
    except (socket.gaierror, UnicodeError) as err:
        reason = err.strerror if isinstance(err, socket.gaierror) else str(err)
        raise UsageError(
            f"--host {host!r} is not an address this machine has ({reason}): use 127.0.0.1 (this "
            "machine only), 0.0.0.0 (every network) or one of its own addresses"
        ) from None
    with socket.socket(family, kind, proto) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind(address)
        except OSError as err:
            raise UsageError(
                f"cannot listen on {host}:{port}: {err.strerror}; choose another --port or --host"
            ) from None
