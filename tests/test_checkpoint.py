"""Checkpoints hold tensors and JSON metadata only; bad files give one clear error."""

from __future__ import annotations

import errno
import os
import pickle
import re
import resource
import signal
import subprocess
import sys
import zipfile

import pytest
import torch

from cartpole.runs import Checkpoint, CheckpointError, load_checkpoint, save_checkpoint


def test_round_trip(tmp_path):
    path = tmp_path / "c.pt"
    save_checkpoint(path, Checkpoint(meta={"agent": "cem", "env_id": "CartPole-v1", "x": [1, 2]},
                                     tensors={"w": torch.arange(4.0)}))  # fmt: skip
    loaded = load_checkpoint(path)
    assert loaded.agent == "cem" and loaded.meta["x"] == [1, 2]
    assert loaded.meta["format_version"] == 1 and "package_version" in loaded.meta
    assert torch.equal(loaded.tensors["w"], torch.arange(4.0))


def test_missing_file(tmp_path):
    with pytest.raises(CheckpointError, match="no checkpoint at"):
        load_checkpoint(tmp_path / "nope.pt")


def test_truncated_file(tmp_path):
    path = tmp_path / "c.pt"
    save_checkpoint(path, Checkpoint(meta={"agent": "cem", "env_id": "CartPole-v1"},
                                     tensors={"w": torch.zeros(1000)}))  # fmt: skip
    path.write_bytes(path.read_bytes()[:300])
    with pytest.raises(CheckpointError, match="truncated or damaged"):
        load_checkpoint(path)


def test_foreign_pickle_is_not_unpickled(tmp_path):
    path = tmp_path / "evil.pt"

    class Boom:
        def __reduce__(self):
            return (print, ("unpickled!",))

    torch.save({"meta": Boom()}, path)
    with pytest.raises(CheckpointError, match="not a cartpole checkpoint"):
        load_checkpoint(path)
    path.write_bytes(pickle.dumps({"a": 1}))
    with pytest.raises(CheckpointError):
        load_checkpoint(path)


def test_other_torch_file_and_future_format(tmp_path):
    path = tmp_path / "other.pt"
    torch.save({"weights": torch.zeros(2)}, path)
    with pytest.raises(CheckpointError, match="not a cartpole checkpoint"):
        load_checkpoint(path)
    torch.save({"meta": '{"format": "cartpole-checkpoint", "format_version": 99}', "tensors": {}}, path)
    with pytest.raises(CheckpointError, match="format 99"):
        load_checkpoint(path)


def test_interrupted_save_keeps_the_previous_file(tmp_path, monkeypatch):
    path = tmp_path / "c.pt"
    save_checkpoint(path, Checkpoint(meta={"agent": "cem", "env_id": "CartPole-v1", "v": 1}))

    def crash(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(torch, "save", crash)
    with pytest.raises(KeyboardInterrupt):
        save_checkpoint(path, Checkpoint(meta={"agent": "cem", "env_id": "CartPole-v1", "v": 2}))
    monkeypatch.undo()
    assert load_checkpoint(path).meta["v"] == 1
    assert [p.name for p in tmp_path.iterdir()] == ["c.pt"]


def test_a_disk_that_fills_up_during_a_save_raises_its_os_error_and_keeps_the_previous_file(tmp_path):
    """A real write failure, not a mock: a file-size limit (RLIMIT_FSIZE, SIGXFSZ ignored) makes the
    write fail with EFBIG partway, as a full disk fails with ENOSPC. The OSError comes out as itself,
    named for the checkpoint (torch's zip writer would turn it into a RuntimeError with no errno)."""
    path = tmp_path / "c.pt"
    save_checkpoint(path, Checkpoint(meta={"agent": "cem", "env_id": "CartPole-v1", "v": 1}))
    soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
    previous = signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (64 * 1024, hard))
    try:
        with pytest.raises(OSError) as raised:
            save_checkpoint(path, Checkpoint(meta={"agent": "cem", "env_id": "CartPole-v1", "v": 2},
                                             tensors={"w": torch.zeros(1_000_000)}))  # fmt: skip
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))
        signal.signal(signal.SIGXFSZ, previous)
    assert raised.value.errno == errno.EFBIG and raised.value.filename == str(path)
    assert load_checkpoint(path).meta["v"] == 1
    assert [p.name for p in tmp_path.iterdir()] == ["c.pt"]


def test_a_save_holds_no_second_copy_of_its_tensors_in_memory(tmp_path):
    """A pixel DQN's checkpoint carries its 600 MB replay: the save streams it into the file, so a
    200 MB tensor raises the peak memory of a fresh process by far less than 200 MB."""
    script = (
        "import resource, sys, torch\n"
        "from cartpole.runs import Checkpoint, save_checkpoint\n"
        "big = torch.ones(200_000_000, dtype=torch.uint8)\n"
        "before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss\n"
        "save_checkpoint(__import__('pathlib').Path(sys.argv[1]),\n"
        "                Checkpoint(meta={'agent': 'dqn', 'env_id': 'x'}, tensors={'replay': big}))\n"
        "print((resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before) // 1024)\n"
    )
    out = subprocess.run([sys.executable, "-c", script, str(tmp_path / "big.pt")], capture_output=True,
                         text=True, check=True, env={**os.environ, "OMP_NUM_THREADS": "1"})  # fmt: skip
    assert int(out.stdout.strip()) < 50, f"the save raised the peak by {out.stdout.strip()} MB"
    assert load_checkpoint(tmp_path / "big.pt").tensors["replay"].shape == (200_000_000,)


# What a file that is not a readable checkpoint is: said in its own words, not lumped together.
NOT_CHECKPOINTS = {
    "empty": (b"", "is empty (0 bytes)"),
    "json": (b'{"agent": "cem"}', "is a JSON or text file, not a checkpoint"),
    "bytes": (bytes(range(7, 250)), "is not a checkpoint: neither a torch zip archive nor a pickle"),
    "pickle": (b"\x80\x04K\x01.", "holds pickled Python objects"),
}


@pytest.mark.parametrize("kind", list(NOT_CHECKPOINTS))
def test_a_file_that_is_not_a_checkpoint_is_named_for_what_it_is(kind, tmp_path):
    content, said = NOT_CHECKPOINTS[kind]
    path = tmp_path / "c.pt"
    path.write_bytes(content)
    with pytest.raises(CheckpointError, match=re.escape(said)):
        load_checkpoint(path)


def test_a_zip_archive_is_not_taken_for_a_damaged_checkpoint(tmp_path):
    path = tmp_path / "c.pt"
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("notes.txt", "hello")
    with pytest.raises(CheckpointError, match="is a zip archive, not a torch checkpoint"):
        load_checkpoint(path)


def test_a_torch_file_of_python_objects_is_refused_as_such(tmp_path):
    path = tmp_path / "c.pt"
    torch.save({"model": torch.nn.Linear(4, 2)}, path)
    with pytest.raises(CheckpointError, match="holds pickled Python objects, which we never load"):
        load_checkpoint(path)
