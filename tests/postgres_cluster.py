"""A private PostgreSQL cluster for tests that stop or restart their server: never the shared one that
`.ci/postgres.sh` starts, which other test workers use at the same time.

`private_postgres` (a fixture: import it into a test module) starts one cluster per test module, as
`.ci/postgres.sh` does (initdb and pg_ctl as the user postgres, listening on 127.0.0.1 only, trust
auth), gives each test a running server and a fresh database, and deletes the cluster after the module.
Where PostgreSQL's binaries (or the user postgres) are missing it skips, except under CI (``CI`` set),
where it fails.
"""

from __future__ import annotations

import getpass
import glob
import os
import shutil
import socket
import subprocess
import tempfile
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest


def postgres_bin() -> Path | None:
    """The folder with initdb, pg_ctl and createdb, or None."""
    found = shutil.which("initdb")
    candidates = [Path(os.path.realpath(found)).parent] if found else []
    candidates += [Path(d) for d in sorted(glob.glob("/usr/lib/postgresql/*/bin"), reverse=True)]
    for folder in candidates:
        if all((folder / tool).is_file() for tool in ("initdb", "pg_ctl", "createdb")):
            return folder
    return None


def can_run_as_postgres() -> bool:
    if getpass.getuser() == "postgres":
        return True
    if os.geteuid() != 0 or shutil.which("runuser") is None:
        return False
    return subprocess.run(["id", "postgres"], capture_output=True).returncode == 0


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@dataclass
class Cluster:
    """One PostgreSQL cluster in ``folder``, on 127.0.0.1:``port``."""

    bin: Path
    folder: Path
    port: int

    def run(self, tool: str, *args: str, timeout: float = 120) -> None:
        command = [str(self.bin / tool), *args]
        if getpass.getuser() != "postgres":
            command = ["runuser", "-u", "postgres", "--", *command]
        subprocess.run(command, check=True, capture_output=True, timeout=timeout)

    def pg_ctl(self, *args: str) -> None:
        self.run("pg_ctl", "-D", str(self.folder / "data"), *args)

    def server_options(self) -> list[str]:
        """The log file (the server must not hold our pipes) and where it listens."""
        options = f"-c listen_addresses=127.0.0.1 -p {self.port} -k {self.folder}"
        return ["-l", str(self.folder / "server.log"), "-o", options]

    def start(self) -> None:
        self.pg_ctl(*self.server_options(), "-w", "start")

    def stop(self) -> None:
        """Stop at once, as a crash would: connections are cut, nothing is shut down cleanly."""
        self.pg_ctl("-m", "immediate", "-w", "stop")

    def restart(self) -> None:
        """``pg_ctl restart -m immediate``: connections cut, the server back with the same options."""
        self.pg_ctl(*self.server_options(), "-m", "immediate", "-w", "restart")

    def running(self) -> bool:
        try:
            self.pg_ctl("status")
        except subprocess.CalledProcessError:
            return False
        return True

    def new_database(self) -> str:
        """A fresh database's URL."""
        name = f"t{uuid.uuid4().hex[:12]}"
        self.run("createdb", "-h", "127.0.0.1", "-p", str(self.port), "-U", "postgres", name)
        return f"postgresql://postgres@127.0.0.1:{self.port}/{name}"


@pytest.fixture(scope="module")
def postgres_cluster() -> Iterator[Cluster]:
    folder = postgres_bin()
    if folder is None or not can_run_as_postgres():
        if os.environ.get("CI"):
            pytest.fail("CI needs PostgreSQL's binaries and the user postgres (apt-get install postgresql)")
        pytest.skip("no PostgreSQL binaries (or no user postgres to run them): apt-get install postgresql")
    home = Path(tempfile.mkdtemp(prefix="cartpole-pg-"))
    if getpass.getuser() != "postgres":
        shutil.chown(home, "postgres")
    cluster = Cluster(folder, home, free_port())
    try:
        cluster.run("initdb", "-D", str(home / "data"), "-U", "postgres", "--auth=trust")
        cluster.start()
        yield cluster
    finally:
        if cluster.running():
            cluster.stop()
        shutil.rmtree(home, ignore_errors=True)


@pytest.fixture
def private_postgres(postgres_cluster: Cluster) -> Cluster:
    """The module's cluster, running (a test before may have stopped it)."""
    if not postgres_cluster.running():
        postgres_cluster.start()
    return postgres_cluster
