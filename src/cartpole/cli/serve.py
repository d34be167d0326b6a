"""``cartpole serve``: the local web app (runs, live learning curves, watch agents, play yourself)."""

from __future__ import annotations

import argparse
import signal
import socket
from pathlib import Path
from typing import Any

INSTALL_HINT = "the web app needs FastAPI and uvicorn: pip install fastapi uvicorn websockets"


def add_parser(sub: Any) -> None:
    parser = sub.add_parser(
        "serve",
        help="start the local web app",
        description=(
            "Serve the web app for the runs under --runs-dir: a runs table, live learning curves, "
            "agents played on a canvas, and CartPole to play yourself. It only reads run folders."
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
    check_can_listen(args.host, args.port)
    runs_dir = Path(args.runs_dir)
    app = create_app(runs_dir, allow_hosts=[args.host, *args.allow_host])
    host = f"[{args.host}]" if ":" in args.host else args.host
    print(f"cartpole web app for {runs_dir.resolve()}/ at http://{host}:{args.port}/  (Ctrl+C to stop)")
    if args.host not in ("127.0.0.1", "localhost", "::1"):
        print(f"warning: bound to {args.host}: other machines can reach this app")
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
