"""What keeps the code correct on Windows and macOS, tested here on Linux through the same code paths:
names every OS accepts, text files in UTF-8, a replace that waits for a reader to let go of its file,
liveness asked of psutil (never a signal), the memory check without /proc, and Watch's episode workers
that follow their server by its process. (Experiment workers: tests/test_worker_stop.py.)"""

from __future__ import annotations

import errno
import json
import os
import subprocess
import sys
import threading
import time
from datetime import UTC, datetime
from pathlib import Path

import psutil
import pytest

from cartpole.cli.main import main
from cartpole.core.file_names import is_portable_name, portable_name
from cartpole.core.names import RunState
from cartpole.experiments.entries import Entry
from cartpole.runs import RunDir, atomic, displayed_state
from cartpole.runs.atomic import write_json_atomic
from cartpole.runs.run_dir import run_name

WINDOWS_REFUSES = set('<>:"/\\|?*') | {chr(c) for c in range(32)}


def legal_everywhere(name: str) -> bool:
    """Windows' rules, written out independently of the code under test."""
    stem = name.partition(".")[0].upper()
    devices = {"CON", "PRN", "AUX", "NUL"} | {f"{d}{i}" for d in ("COM", "LPT") for i in range(1, 10)}
    return (
        bool(name)
        and not WINDOWS_REFUSES & set(name)
        and not name.endswith((".", " "))
        and stem not in devices
    )


# ---------------------------------------------------------------------------------------------------
# Names
# ---------------------------------------------------------------------------------------------------

NASTY = [
    "mypkg:MyEnv-v0",
    "ALE/Pong-v5",
    'a<b>c:d"e/f\\g|h?i*j',
    "tab\tnew\nline\x00end\x1f",
    "ends in a dot.",
    "ends in a space ",
    "nul",
    "COM1.toml",
    "lpt9.tar.gz",
    "...",
    "",
    "ünïcødé-v1",
    "C:\\presets\\fast.toml",
]


@pytest.mark.parametrize("text", NASTY)
def test_a_portable_name_is_legal_on_windows_and_is_its_own_portable_name(text):
    name = portable_name(text)
    assert legal_everywhere(name) and is_portable_name(name), name
    assert portable_name(name) == name


def test_portable_names_keep_what_they_can():
    assert portable_name("mypkg:MyEnv-v0") == "mypkg-MyEnv-v0"
    assert portable_name("ALE/Pong-v5") == "ALE-Pong-v5"
    assert portable_name("CartPole-v1") == "CartPole-v1"
    assert portable_name("nul.toml") == "nul_.toml"


@pytest.mark.parametrize("name", ["nul", "Con", "COM3.json", "x.", "a:b", "a b", "", "."])
def test_a_name_windows_refuses_is_not_portable(name):
    assert not is_portable_name(name)


def test_a_run_of_a_module_qualified_env_id_gets_a_folder_name_windows_accepts(tmp_path):
    when = datetime(2025, 1, 2, 3, 4, 5, tzinfo=UTC)
    name = run_name("mypkg:MyEnv-v0", "cem", 0, when)
    assert ":" not in name and legal_everywhere(name)
    assert name == "mypkg-MyEnv-v0__cem__s0__20250102-030405"
    assert run_name("ALE/Pong-v5", "dqn", 3, when) == "ALE-Pong-v5__dqn__s3__20250102-030405"  # as before
    run = RunDir.create(tmp_path, "mypkg:MyEnv-v0", "cem", 0)
    assert run.path.is_dir() and legal_everywhere(run.name)


def test_the_web_app_serves_a_run_of_a_module_qualified_env_id(tmp_path):
    from cartpole.web.runs_folder import RunsFolder

    run = RunDir.create(tmp_path, "mypkg:MyEnv-v0", "cem", 0)
    assert RunsFolder(tmp_path).run(run.name).path == run.path


@pytest.mark.parametrize(
    "preset", ["C:\\presets\\fast|v2.toml", "my:preset?.toml", "trailing.", "../up/nul.toml"]
)
def test_a_compare_entrys_file_names_are_legal_on_windows(preset):
    slug = Entry("cem", preset).slug
    assert legal_everywhere(slug) and legal_everywhere(f"{slug}__s0.json")
    assert slug.startswith("cem-")


@pytest.mark.parametrize("name", ["nul", "COM1", "results."])
def test_an_experiment_name_windows_refuses_is_one_line(name, tmp_path, capsys):
    runs_dir = tmp_path / "runs"
    argv = ["compare", "cem", "--budget", "2gen", "--name", name, "--runs-dir", str(runs_dir)]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "not a folder name on Windows" in err and len(err.strip().splitlines()) == 1
    assert not runs_dir.exists()


def test_a_study_name_windows_refuses_is_one_line(tmp_path, capsys):
    runs_dir = tmp_path / "runs"
    argv = ["sweep", "cem", "--trials", "1", "--study", "aux", "--budget", "2gen"]
    assert main([*argv, "--runs-dir", str(runs_dir)]) == 2
    err = capsys.readouterr().err
    assert "study name 'aux' is not a folder name on Windows" in err and len(err.strip().splitlines()) == 1
    assert not runs_dir.exists()


# ---------------------------------------------------------------------------------------------------
# Text files: UTF-8 on every OS (Windows' default encoding is the locale's, often cp1252)
# ---------------------------------------------------------------------------------------------------


def test_training_reads_and_writes_its_text_files_as_utf8_whatever_the_locale(tmp_path):
    """Under ``-X warn_default_encoding`` an ``open()`` or ``read_text()`` left to the locale's
    encoding warns: none of ours may."""
    import re

    import cartpole

    command = [
        sys.executable,
        "-X",
        "warn_default_encoding",
        "-W",
        "default::EncodingWarning",
        "-m",
        "cartpole",
    ]
    args = ["train", "cem", "--budget", "2gen", "--quiet", "--runs-dir", str(tmp_path / "runs")]
    done = subprocess.run([*command, *args], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    package = Path(cartpole.__file__).parent
    warned = [
        Path(m.group(1)) for m in re.finditer(r"^(.+?):\d+: EncodingWarning", done.stderr, re.MULTILINE)
    ]
    assert not [path for path in warned if path.is_relative_to(package)], done.stderr


# ---------------------------------------------------------------------------------------------------
# A replace while a reader holds the file (Windows refuses it with PermissionError meanwhile)
# ---------------------------------------------------------------------------------------------------


def refusing_replace(monkeypatch, refusals: int, error: OSError) -> list[int]:
    """``os.replace`` refused ``refusals`` times with ``error``, then done; the list counts the tries."""
    tries: list[int] = []
    real = os.replace

    def replace(source, target):
        tries.append(1)
        if len(tries) <= refusals:
            raise error
        real(source, target)

    monkeypatch.setattr(os, "replace", replace)
    return tries


def leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


def test_a_replace_refused_while_a_reader_has_the_file_open_succeeds_once_it_lets_go(tmp_path, monkeypatch):
    path = tmp_path / "status.json"
    write_json_atomic(path, {"state": "old"})
    tries = refusing_replace(monkeypatch, 3, PermissionError(errno.EACCES, "Access is denied"))
    write_json_atomic(path, {"state": "new"})
    assert len(tries) == 4
    assert json.loads(path.read_text()) == {"state": "new"}
    assert leftovers(tmp_path) == []


def test_a_replace_refused_for_good_is_named_for_the_file_and_leaves_the_old_one(tmp_path, monkeypatch):
    path = tmp_path / "status.json"
    write_json_atomic(path, {"state": "old"})
    monkeypatch.setattr(atomic, "REPLACE_RETRY_SECONDS", 0.4)
    tries = refusing_replace(monkeypatch, 10**6, PermissionError(errno.EACCES, "Access is denied"))
    started = time.monotonic()
    with pytest.raises(PermissionError) as error:
        write_json_atomic(path, {"state": "new"})
    assert error.value.filename == str(path) and error.value.errno == errno.EACCES
    assert 1 < len(tries) < 10 and time.monotonic() - started < 2
    assert json.loads(path.read_text()) == {"state": "old"}
    assert leftovers(tmp_path) == []


def test_a_replace_that_fails_otherwise_is_not_tried_again(tmp_path, monkeypatch):
    path = tmp_path / "status.json"
    tries = refusing_replace(monkeypatch, 1, OSError(errno.ENOSPC, "No space left on device"))
    with pytest.raises(OSError) as error:
        write_json_atomic(path, {"state": "new"})
    assert error.value.errno == errno.ENOSPC and error.value.filename == str(path)
    assert len(tries) == 1


# ---------------------------------------------------------------------------------------------------
# Whether a run's process lives: asked of psutil, never with a signal (on Windows, signal 0 is Ctrl-C)
# ---------------------------------------------------------------------------------------------------


def test_a_runs_process_is_one_process_never_a_group():
    """kill(pid, 0) took 0 and -1 for process groups (and on Windows sends Ctrl-C to one): a status
    with such a pid shows no live run."""
    import socket

    now = time.time()
    running = {"state": "running", "host": socket.gethostname(), "heartbeat": now}
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    assert displayed_state(running | {"pid": os.getpid()}, now) == RunState.RUNNING
    assert displayed_state(running | {"pid": 1}, now) == RunState.RUNNING  # another user's process
    assert displayed_state(running | {"pid": dead.pid}, now) == RunState.CRASHED
    for pid in (0, -1, 2**40):
        assert displayed_state(running | {"pid": pid}, now) == RunState.CRASHED


# ---------------------------------------------------------------------------------------------------
# Memory: the available memory, and glibc's allocator thresholds (Linux only)
# ---------------------------------------------------------------------------------------------------


def test_the_memory_check_works_where_there_is_no_proc_meminfo(tmp_path, monkeypatch):
    """macOS and Windows have no /proc/meminfo: the available memory comes from psutil, so a count too
    large for the machine still gets its one line there."""
    from cartpole.core import memory

    on_linux = memory.available_memory()
    monkeypatch.setattr(memory, "MEMINFO", str(tmp_path / "no-such-file"))
    elsewhere = memory.available_memory()
    assert elsewhere is not None and elsewhere > 0
    if on_linux is not None:  # the same measure (MemAvailable), a moment apart
        assert abs(elsewhere - on_linux) < 0.25 * on_linux
    fits, free = memory.fits_in_memory(2**60)  # an exbibyte
    assert not fits and free is not None


@pytest.mark.parametrize("system, libc", [("Windows", ""), ("Darwin", ""), ("Linux", "musl")])
def test_the_allocator_thresholds_are_left_alone_without_glibc(system, libc, monkeypatch):
    """glibc's mallopt and MALLOC_* variables mean nothing elsewhere: nothing is called or set."""
    import ctypes
    import platform

    from cartpole.cli.allocator import VARIABLES, keep_freed_memory

    for variable in VARIABLES.values():
        monkeypatch.delenv(variable, raising=False)
    monkeypatch.setattr(platform, "system", lambda: system)
    monkeypatch.setattr(platform, "libc_ver", lambda *args, **kwargs: (libc, ""))

    def no_libc(*args, **kwargs):
        raise AssertionError("no C library is loaded without glibc")

    monkeypatch.setattr(ctypes, "CDLL", no_libc)
    assert keep_freed_memory() is False
    assert not any(variable in os.environ for variable in VARIABLES.values())


# ---------------------------------------------------------------------------------------------------
# Watch's episode workers: below the server's priority, and gone with it
# ---------------------------------------------------------------------------------------------------


def test_wait_for_end_returns_when_the_process_dies_even_unreaped():
    from cartpole.web.episodes import wait_for_end

    server = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(120)"])
    try:
        started = psutil.Process(server.pid).create_time()
        watcher = threading.Thread(target=wait_for_end, args=(server.pid, started, 0.05), daemon=True)
        watcher.start()
        watcher.join(0.5)
        assert watcher.is_alive(), "it returned while the process lives"
        server.kill()  # not reaped: a zombie until wait() below
        watcher.join(10)
        assert not watcher.is_alive(), "it waits on for a dead process"
    finally:
        server.kill()
        server.wait()


def test_wait_for_end_returns_at_once_for_a_pid_that_names_another_process():
    from cartpole.web.episodes import wait_for_end

    me = psutil.Process()
    watcher = threading.Thread(target=wait_for_end, args=(me.pid, me.create_time() - 3600, 0.05), daemon=True)
    watcher.start()
    watcher.join(5)
    assert not watcher.is_alive()


@pytest.mark.skipif(not hasattr(os, "nice"), reason="POSIX niceness (Windows: a priority class)")
def test_an_episode_worker_runs_below_the_servers_priority():
    from cartpole.web.episodes import WORKER_NICENESS, EpisodeWorkers

    expected = min(19, os.nice(0) + WORKER_NICENESS)
    workers = EpisodeWorkers()
    workers.start()
    try:
        deadline = time.monotonic() + 60
        niced = False
        while not niced and time.monotonic() < deadline:
            time.sleep(0.1)
            for child in psutil.Process().children():
                try:
                    niced = niced or child.nice() == expected
                except psutil.Error:
                    continue
        assert niced, "no episode worker lowered its priority"
    finally:
        workers.close()
