"""Worker slots of `compare` and `sweep`: `--jobs`/`--workers` CPU slots, `--gpus` GPU slots, `--device`.

This machine has no GPU: the allocation is tested as a function of the GPUs it is told torch sees, a GPU
slot's worker through the process it starts, and the refusals and the recorded device end to end.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from cartpole.experiments.entries import ExperimentError
from cartpole.experiments.processes import Job, run_jobs
from cartpole.experiments.slots import CPU, CUDA_VISIBLE, allocate_slots, gpu_slot, visible_gpus


def test_cpu_is_the_default_and_jobs_counts_its_slots():
    assert allocate_slots(None, None, None, ["0", "1"]) == [CPU]
    assert allocate_slots(None, 3, None, ["0", "1"]) == [CPU] * 3
    assert allocate_slots("cpu", 2, None, []) == [CPU] * 2


def test_gpus_gives_a_slot_per_gpu_each_seeing_its_own():
    slots = allocate_slots(None, None, "2", ["0", "1", "2"])
    assert slots == [gpu_slot("0"), gpu_slot("1")]
    assert [s.device for s in slots] == ["cuda", "cuda"]
    assert [s.environment[CUDA_VISIBLE] for s in slots] == ["0", "1"]
    assert allocate_slots("cuda", None, "all", ["4", "6"]) == [gpu_slot("4"), gpu_slot("6")]
    assert allocate_slots("cuda", None, None, ["4", "6"]) == [gpu_slot("4"), gpu_slot("6")]


def test_auto_takes_both_kinds_and_is_the_cpu_without_gpus():
    assert allocate_slots("auto", 2, "1", ["0", "1"]) == [gpu_slot("0"), CPU, CPU]
    assert allocate_slots("auto", None, None, ["0"]) == [gpu_slot("0")]
    assert allocate_slots("auto", None, None, []) == [CPU]
    assert allocate_slots("auto", 2, None, []) == [CPU, CPU]


@pytest.mark.parametrize(
    ("device", "jobs", "gpus", "visible", "message"),
    [
        ("cuda", None, None, [], "--device cuda: torch sees no CUDA GPU on this machine"),
        (None, None, "2", ["0"], "--gpus 2: torch sees 1 GPU(s) on this machine"),
        ("auto", None, "1", [], "--gpus 1: torch sees 0 GPU(s)"),
        ("cpu", None, "1", ["0"], "--gpus 1 trains on GPUs, not with --device cpu"),
        ("cuda", 2, None, ["0"], "--jobs counts CPU slots, and --device cuda trains on GPUs only"),
        (None, None, "two", ["0"], "--gpus takes a count or 'all', got 'two'"),
        (None, 0, None, [], "--jobs must be >= 1, got 0"),
        ("cuda", None, "0", ["0"], "leaves no slot to train in"),
    ],
)
def test_slots_that_cannot_be_had_are_refused_in_one_line(device, jobs, gpus, visible, message):
    with pytest.raises(ExperimentError, match=message.replace("(", r"\(").replace(")", r"\)")):
        allocate_slots(device, jobs, gpus, visible)


def test_visible_gpus_are_those_torch_counts_named_as_cuda_visible_devices_names_them():
    # this machine's torch sees no GPU, whatever the variable says
    assert visible_gpus({}) == []
    assert visible_gpus({CUDA_VISIBLE: "3,5"}) == []


SHOW = "import json, os, sys; print(json.dumps([sys.argv[1:], os.environ.get('CUDA_VISIBLE_DEVICES')]))"


def test_each_slot_starts_its_worker_with_its_device_and_its_own_gpu(tmp_path):
    jobs = [Job([sys.executable, "-c", SHOW, f"job{i}"], tmp_path / f"job{i}.log", i) for i in range(4)]
    ended: list[int] = []
    run_jobs(jobs, [gpu_slot("0"), gpu_slot("1"), CPU], lambda job, code: ended.append(code))
    assert ended == [0] * 4
    seen = [json.loads((tmp_path / f"job{i}.log").read_text()) for i in range(4)]
    # three slots, four jobs: the first three start together, the fourth takes the first slot freed
    assert seen[0] == [["job0", "--device", "cuda"], "0"]
    assert seen[1] == [["job1", "--device", "cuda"], "1"]
    assert seen[2][0] == ["job2", "--device", "cpu"]
    assert seen[3][0][1:] in (["--device", "cuda"], ["--device", "cpu"])


def cartpole(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "cartpole", *args], capture_output=True, text=True, cwd=cwd, timeout=300
    )


@pytest.mark.parametrize("command", [["compare", "cem"], ["sweep", "cem", "--trials", "1", "--study", "s"]])
@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (
            ["--device", "cuda"],
            "--device cuda: torch sees no CUDA GPU on this machine; use --device cpu or auto",
        ),
        (["--gpus", "1"], "--gpus 1: torch sees 0 GPU(s) on this machine; ask for at most 0 (or --gpus all)"),
    ],
)
def test_compare_and_sweep_refuse_gpus_this_machine_has_not(tmp_path, command, flags, message):
    done = cartpole(*command, *flags, "--runs-dir", str(tmp_path), cwd=tmp_path)
    assert done.returncode == 2, done.stderr
    (line,) = done.stderr.strip().splitlines()
    assert line.endswith("error: " + message) and "Traceback" not in done.stderr
    assert not (tmp_path / "experiments").exists() and not (tmp_path / "sweeps").exists()


def test_a_compare_record_and_report_say_the_device(tmp_path):
    done = cartpole(
        "compare", "cem", "--seeds", "1", "--budget", "2gen", "--device", "cpu", "--name", "dev",
        "--runs-dir", str(tmp_path), cwd=tmp_path,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    folder = tmp_path / "experiments" / "dev"
    record = json.loads((folder / "records" / "cem__s0.json").read_text())
    assert record["device"] == "cpu"
    assert json.loads((folder / "report.json").read_text())["entries"][0]["devices"] == ["cpu"]


def test_a_sweep_trial_says_its_device(tmp_path):
    import optuna
    from optuna.storages.journal import JournalFileBackend

    done = cartpole(
        "sweep", "cem", "--trials", "1", "--seeds", "1", "--budget", "2gen", "--study", "dev",
        "--device", "cpu", "--runs-dir", str(tmp_path), cwd=tmp_path,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    journal = JournalFileBackend(str(tmp_path / "sweeps" / "dev" / "journal.log"))
    study = optuna.load_study(study_name="dev", storage=optuna.storages.JournalStorage(journal))
    assert [t.user_attrs["device"] for t in study.get_trials()] == ["cpu"]
