"""Bad input and damaged files, table-driven: every case exits 2 with one line on stderr, no traceback,
and leaves every saved file byte-for-byte as it was. Plus property tests of the budget and ``--set``
parsers, and a full disk / read-only file system simulated by injecting the OS error."""

from __future__ import annotations

import errno
import hashlib
import json
import os
import shutil
from collections.abc import Callable
from pathlib import Path

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from cartpole.cli.main import main
from cartpole.core import memory
from cartpole.core.config import build_config
from cartpole.core.errors import ConfigError
from cartpole.runs import RunDir, load_checkpoint
from cartpole.training import train
from cartpole.training.budget import MAX_COUNT, Budget, BudgetError, parse_budget
from cartpole.training.config import TrainSettings

# --- material: two small real runs, copied fresh for every case ------------------------------------


@pytest.fixture(scope="module")
def originals(tmp_path_factory: pytest.TempPathFactory, cem_run: Path) -> dict[str, Path]:
    """A solved CEM run (best, solved, latest) and a short DQN run (best, latest), both resumable."""
    runs_dir = tmp_path_factory.mktemp("dqn-runs")
    dqn = train(
        "dqn", seed=0, budget="1200", runs_dir=runs_dir, overrides={"eval_every": "100000"}, quiet=True
    ).run.path
    return {"cem": cem_run, "dqn": dqn}


@pytest.fixture
def runs(tmp_path: Path, originals: dict[str, Path]) -> dict[str, Path]:
    """Copies of the runs in ``tmp_path/runs``, marked interrupted so that ``--resume`` would go on."""
    copies = {}
    for kind, path in originals.items():
        copy = tmp_path / "runs" / path.name
        shutil.copytree(path, copy)
        status = json.loads((copy / "status.json").read_text())
        (copy / "status.json").write_text(json.dumps({**status, "state": "interrupted"}))
        copies[kind] = copy
    return copies


def fingerprint(folder: Path) -> dict[str, str]:
    """Every file (and link) under ``folder``: its SHA-256, or where the link points."""
    found = {}
    for path in sorted(folder.rglob("*")):
        key = str(path.relative_to(folder))
        if path.is_symlink():
            found[key] = f"link to {os.readlink(path)}"
        elif path.is_file():
            found[key] = hashlib.sha256(path.read_bytes()).hexdigest()
    return found


def assert_one_line_exit_2(code: int, err: str, command: str) -> None:
    assert code == 2, err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert err.startswith(f"cartpole {command}: error: ") or err.startswith("cartpole: error: "), err


# --- damage done to a run folder --------------------------------------------------------------------

Damage = Callable[[dict[str, Path]], Path]
"""Damages one of the run copies and returns that run's folder."""


def edit_json(name: str, change: Callable[[dict], object], kind: str = "cem") -> Damage:
    def damage(runs: dict[str, Path]) -> Path:
        path = runs[kind] / name
        path.write_text(json.dumps(change(json.loads(path.read_text()))))
        return runs[kind]

    return damage


def write_text(name: str, text: str, kind: str = "cem") -> Damage:
    def damage(runs: dict[str, Path]) -> Path:
        path = runs[kind] / name
        path.unlink()
        path.write_text(text)
        return runs[kind]

    return damage


def dangling(name: str, kind: str = "cem") -> Damage:
    def damage(runs: dict[str, Path]) -> Path:
        (runs[kind] / name).unlink()
        (runs[kind] / name).symlink_to(runs[kind] / "gone")
        return runs[kind]

    return damage


def truncated(name: str, kind: str = "cem") -> Damage:
    def damage(runs: dict[str, Path]) -> Path:
        path = runs[kind] / name
        path.write_bytes(path.read_bytes()[:300])
        return runs[kind]

    return damage


def pickled(name: str, kind: str = "cem") -> Damage:
    def damage(runs: dict[str, Path]) -> Path:
        torch.save({"model": torch.nn.Linear(4, 2)}, runs[kind] / name)
        return runs[kind]

    return damage


def with_meta(name: str, change: Callable[[dict], dict], kind: str = "cem") -> Damage:
    """Rewrite a checkpoint's metadata (the tensors stay)."""

    def damage(runs: dict[str, Path]) -> Path:
        path = runs[kind] / name
        payload = torch.load(path, weights_only=True)
        payload["meta"] = json.dumps(change(json.loads(payload["meta"])))
        torch.save(payload, path)
        return runs[kind]

    return damage


def with_tensors(name: str, change: Callable[[dict], dict], kind: str = "cem") -> Damage:
    def damage(runs: dict[str, Path]) -> Path:
        path = runs[kind] / name
        payload = torch.load(path, weights_only=True)
        payload["tensors"] = change(payload["tensors"])
        torch.save(payload, path)
        return runs[kind]

    return damage


def swapped_latest(runs: dict[str, Path]) -> Path:
    """The DQN run's latest.pt in the CEM run: a checkpoint of another run."""
    shutil.copy(runs["dqn"] / "checkpoints" / "latest.pt", runs["cem"] / "checkpoints" / "latest.pt")
    return runs["cem"]


def dqn_config(change: Callable[[dict], None]) -> Damage:
    def edit(record: dict) -> dict:
        change(record["config"])
        return record

    return edit_json("config.json", edit, kind="dqn")


def all_checkpoints(damage: Callable[[str], Damage]) -> Damage:
    def damage_all(runs: dict[str, Path]) -> Path:
        for name in ("best", "solved", "latest"):
            damage(f"checkpoints/{name}.pt")(runs)
        return runs["cem"]

    return damage_all


LATEST = "checkpoints/latest.pt"
RESUME_DAMAGE: dict[str, Damage] = {
    "config not JSON": write_text("config.json", "{not json"),
    "config empty": write_text("config.json", ""),
    "config a list": write_text("config.json", "[1, 2]"),
    "config not UTF-8": lambda runs: [(runs["cem"] / "config.json").write_bytes(b"\xff\xfe{"), runs["cem"]][
        1
    ],
    "config without agent": edit_json("config.json", lambda c: {k: v for k, v in c.items() if k != "agent"}),
    "config without settings": edit_json(
        "config.json", lambda c: {k: v for k, v in c.items() if k != "settings"}
    ),
    "config agent a number": edit_json("config.json", lambda c: {**c, "agent": 3}),
    "config unknown agent": edit_json("config.json", lambda c: {**c, "agent": "ppo9"}),
    "config unknown env": edit_json("config.json", lambda c: {**c, "env_id": "Nope-v0"}),
    "config seed text": edit_json("config.json", lambda c: {**c, "seed": "0"}),
    "config seed true": edit_json("config.json", lambda c: {**c, "seed": True}),
    "config seed negative": edit_json("config.json", lambda c: {**c, "seed": -4}),
    "config settings a list": edit_json("config.json", lambda c: {**c, "settings": []}),
    "config unknown setting": edit_json("config.json", lambda c: {**c, "config": {**c["config"], "x": 1}}),
    "config bad setting": edit_json(
        "config.json", lambda c: {**c, "config": {**c["config"], "population": -2}}
    ),
    "config setting nan text": edit_json(
        "config.json", lambda c: {**c, "config": {**c["config"], "elite_fraction": "nan"}}
    ),
    "config budget a number": edit_json("config.json", lambda c: {**c, "budget": 5}),
    "config budget text": edit_json("config.json", lambda c: {**c, "budget": {"env_steps": "lots"}}),
    "config budget zero": edit_json("config.json", lambda c: {**c, "budget": {"env_steps": 0}}),
    "config budget unknown": edit_json("config.json", lambda c: {**c, "budget": {"weeks": 2}}),
    "config dangling link": dangling("config.json"),
    "status not JSON": write_text("status.json", "{"),
    "status a list": write_text("status.json", "[]"),
    "status state a number": edit_json("status.json", lambda s: {**s, "state": 7}),
    "status steps text": edit_json("status.json", lambda s: {**s, "env_steps": "many"}),
    "eval not JSON": write_text("eval.json", "nope"),
    "eval a string": write_text("eval.json", '"solved"'),
    "eval solved text": edit_json("eval.json", lambda e: {**e, "solved": "yes"}),
    "eval without verdict": edit_json("eval.json", lambda e: {k: v for k, v in e.items() if k != "verdict"}),
    "latest truncated": truncated(LATEST),
    "latest text": write_text(LATEST, "not a checkpoint"),
    "latest empty": write_text(LATEST, ""),
    "latest dangling link": dangling(LATEST),
    "latest pickled": pickled(LATEST),
    "latest of another run": swapped_latest,
    "latest without learner": with_meta(LATEST, lambda m: {k: v for k, v in m.items() if k != "learner"}),
    "latest without loop": with_meta(LATEST, lambda m: {k: v for k, v in m.items() if k != "loop"}),
    "latest loop a list": with_meta(LATEST, lambda m: {**m, "loop": [1]}),
    "latest without agent": with_meta(LATEST, lambda m: {k: v for k, v in m.items() if k != "agent"}),
    "latest meta a list": with_meta(LATEST, lambda m: [m]),
    "latest future format": with_meta(LATEST, lambda m: {**m, "format_version": 99}),
    "latest not resumable": with_meta(LATEST, lambda m: {**m, "resumable": False}),
    "latest without tensors": with_tensors(LATEST, lambda t: {}),
    "latest tensors not tensors": with_tensors(LATEST, lambda t: {k: 1 for k in t}),
    "latest tensor wrong size": with_tensors(LATEST, lambda t: {**t, "params": torch.zeros(3)}),
    "dqn latest without replay": with_tensors(
        LATEST, lambda t: {k: v for k, v in t.items() if not k.startswith("replay")}, kind="dqn"
    ),
    "dqn net smaller than latest": dqn_config(lambda c: c.update(hidden_sizes=[8])),
    "dqn buffer smaller than latest": dqn_config(lambda c: c.update(buffer_size=10)),
    "dqn lr infinite": dqn_config(lambda c: c.update(lr="inf")),
}


def dqn_wrong_layers(runs: dict[str, Path]) -> Path:
    """Every DQN checkpoint's first layer swapped for one of another size."""
    for name in ("best", "latest"):
        path = runs["dqn"] / "checkpoints" / f"{name}.pt"
        payload = torch.load(path, weights_only=True)
        first = next(key for key in payload["tensors"] if key.startswith("q_net.") and key.endswith("weight"))
        payload["tensors"][first] = torch.zeros(3, 3)
        torch.save(payload, path)
    return runs["dqn"]


EVAL_DAMAGE: dict[str, Damage] = {
    "every checkpoint truncated": all_checkpoints(truncated),
    "every checkpoint text": all_checkpoints(lambda name: write_text(name, "garbage")),
    "every checkpoint a dangling link": all_checkpoints(dangling),
    "every checkpoint pickled": all_checkpoints(pickled),
    "every checkpoint without tensors": all_checkpoints(lambda name: with_tensors(name, lambda t: {})),
    "every checkpoint of an unknown agent": all_checkpoints(
        lambda name: with_meta(name, lambda m: {**m, "agent": "sarsa"})
    ),
    "every checkpoint with wrong-size tensors": all_checkpoints(
        lambda name: with_tensors(name, lambda t: {**t, "params": torch.zeros(2, 2)})
    ),
    "every checkpoint without learner data": all_checkpoints(
        lambda name: with_meta(name, lambda m: {k: v for k, v in m.items() if k != "learner"})
    ),
    "dqn checkpoints with wrong layers": dqn_wrong_layers,
    "no checkpoints at all": lambda runs: [shutil.rmtree(runs["cem"] / "checkpoints"), runs["cem"]][-1],
}


@pytest.mark.parametrize("case", sorted(RESUME_DAMAGE))
def test_resume_of_a_damaged_run_is_one_line(case, runs, capsys):
    run = RESUME_DAMAGE[case](runs)
    before = fingerprint(run.parent)
    code = main(["train", "--resume", str(run), "--quiet", "--device", "cpu"])
    assert_one_line_exit_2(code, capsys.readouterr().err, "train")
    assert fingerprint(run.parent) == before


@pytest.mark.parametrize("command", ["eval", "record"])
@pytest.mark.parametrize("case", sorted(EVAL_DAMAGE))
def test_eval_and_record_of_damaged_checkpoints_are_one_line(case, command, runs, tmp_path, capsys):
    run = EVAL_DAMAGE[case](runs)
    before = fingerprint(run.parent)
    out = ["--out", str(tmp_path / "video.gif")] if command == "record" else []
    code = main([command, str(run), "--episodes", "2", *out])
    assert_one_line_exit_2(code, capsys.readouterr().err, command)
    assert fingerprint(run.parent) == before and not (tmp_path / "video.gif").exists()


def test_eval_falls_back_from_a_corrupt_best_to_solved_then_latest(runs, capsys):
    truncated("checkpoints/best.pt")(runs)
    assert main(["eval", str(runs["cem"]), "--episodes", "2", "--json"]) == 0
    out, err = capsys.readouterr()
    assert json.loads(out)["checkpoint"].endswith("solved.pt")
    assert "best.pt is truncated or damaged" in err and "using" in err and "solved.pt" in err
    pickled("checkpoints/solved.pt")(runs)
    assert main(["eval", str(runs["cem"]), "--episodes", "2", "--json"]) == 0
    out, err = capsys.readouterr()
    assert json.loads(out)["checkpoint"].endswith("latest.pt")
    assert "best.pt" in err and "solved.pt" in err and "pickled" in err


@pytest.mark.parametrize("kind", ["cem", "dqn"])
def test_a_checkpoint_evaluated_on_another_env_is_one_line(kind, runs, capsys):
    code = main(["eval", str(runs[kind]), "--env", "Acrobot-v1", "--episodes", "2"])
    err = capsys.readouterr().err
    assert_one_line_exit_2(code, err, "eval")
    assert "CartPole-v1 (4 observations, 2 actions)" in err and "Acrobot-v1 has 6 observations" in err


def test_a_pickled_checkpoint_is_refused_in_a_whole_sentence(runs, capsys):
    pickled(LATEST)(runs)
    assert main(["eval", str(runs["cem"] / LATEST)]) == 2
    err = capsys.readouterr().err.strip()
    assert "pickled Python objects" in err and err.endswith("use a checkpoint written by `cartpole train`")


# --- bad values: refused before a run folder exists ------------------------------------------------

BAD_TRAIN_VALUES = {
    "lr inf": ["dqn", "--set", "lr=inf"],
    "lr nan": ["dqn", "--set", "lr=nan"],
    "lr -inf": ["dqn", "--set", "lr=-inf"],
    "gamma nan": ["dqn", "--set", "gamma=NaN"],
    "tau text": ["dqn", "--set", "tau=fast"],
    "cem elite_fraction inf": ["cem", "--set", "elite_fraction=inf"],
    "batch_size 2.5": ["dqn", "--set", "batch_size=2.5"],
    "batch_size 1e400": ["dqn", "--set", "batch_size=1e400"],
    "eval_every inf": ["cem", "--set", "eval_every=inf"],
    "hidden_sizes empty": ["ppo", "--set", "hidden_sizes="],  # (DQN may have none: a linear head)
    "hidden_sizes 0": ["dqn", "--set", "hidden_sizes=0"],
    "hidden_sizes 1.5": ["dqn", "--set", "hidden_sizes=1.5"],
    "buffer_size too big": ["dqn", "--set", "buffer_size=1e15"],
    "hidden_sizes too big": ["dqn", "--set", "hidden_sizes=200000,200000"],
    "stop_when_solved maybe": ["cem", "--set", "stop_when_solved=maybe"],
    "budget setting": ["cem", "--set", "budget=lots"],
    "budget setting 0.5": ["cem", "--set", "budget=0.5"],
    "budget 1e400": ["cem", "--budget", "1e400"],
    "budget 0.5": ["cem", "--budget", "0.5"],
    "budget empty": ["cem", "--budget", ""],
    "budget 1.5gen": ["cem", "--budget", "1.5gen"],
    "budget 0": ["cem", "--budget", "0"],
    "budget 0s": ["cem", "--budget", "0s"],
    "budget -5": ["cem", "--budget", "-5"],
    "budget inf": ["cem", "--budget", "inf"],
    "budget nan": ["cem", "--budget", "nan"],
    "budget 1e400s": ["cem", "--budget", "1e400s"],
    "budget 2.5ep": ["cem", "--budget", "2.5ep"],
    "seed huge": ["cem", "--seed", str(2**70)],
    "preset unknown": ["cem", "--preset", "turbo"],
    "env continuous": ["cem", "--env", "Pendulum-v1"],
    "observation_std of another length": ["ppo", "--set", "observation_std=1,2,3"],
    "observation_mean of another length": ["a2c", "--env", "MountainCar-v0", "--set", "observation_mean=0"],
    "observation_std 0": ["reinforce", "--set", "observation_std=1,0,1,1"],
    "observation_std nan": ["ppo", "--set", "observation_std=1,nan,1,1"],
    "observation_mean on images": [
        *("ppo", "--env", "cartpole/CartPolePixels-v1"),
        *("--set", "observation_mean=0"),
    ],
    # a unit that means nothing to the agent (DQN learns in steps of 8 env steps, not generations)
    "budget in generations for dqn": ["dqn", "--budget", "5gen"],
    "budget in generations for ppo": ["ppo", "--budget", "2gen"],
    "budget in generations as a setting": ["a2c", "--set", "budget=3gen"],
    "seeds: a count of none": ["cem", "--seeds", "0"],
}


@pytest.mark.parametrize("case", sorted(BAD_TRAIN_VALUES))
def test_bad_values_are_refused_before_a_run_folder_exists(case, tmp_path, capsys):
    runs_dir = tmp_path / "runs"
    code = main(["train", *BAD_TRAIN_VALUES[case], "--runs-dir", str(runs_dir), "--quiet"])
    assert_one_line_exit_2(code, capsys.readouterr().err, "train")
    assert not runs_dir.exists()


def test_a_memory_estimate_says_how_much(tmp_path, capsys):
    """The agent's own estimate of a seed's bytes: 10^13 replay rows of 11 float32s, about 400 TiB."""
    code = main(["train", "dqn", "--set", "buffer_size=1e13", "--runs-dir", str(tmp_path / "r"), "--quiet"])
    err = capsys.readouterr().err
    assert_one_line_exit_2(code, err, "train")
    assert "this run of dqn would take about 400.2 TiB of memory but " in err
    assert err.rstrip().endswith("is available; use smaller settings")
    assert not (tmp_path / "r").exists()


def test_a_resume_checks_the_memory_before_it_allocates(tmp_path, capsys, monkeypatch):
    """A run resumed where less memory is available than its seeds take: one line, nothing lost."""
    outcome = train("cem", seed=1, budget="2gen", runs_dir=tmp_path, stop_when_solved=False)
    status = json.loads((outcome.run.path / "status.json").read_text())
    (outcome.run.path / "status.json").write_text(json.dumps(status | {"state": "interrupted"}))
    meminfo = tmp_path / "meminfo"
    meminfo.write_text("MemTotal:  16 kB\nMemAvailable:  1 kB\n")
    monkeypatch.setattr(memory, "MEMINFO", str(meminfo))
    before = fingerprint(tmp_path)
    code = main(["train", "--resume", str(outcome.run.path)])
    err = capsys.readouterr().err
    assert_one_line_exit_2(code, err, "train")
    assert "this run of cem would take about" in err and "but 1.0 KiB is available" in err
    assert fingerprint(tmp_path) == before


def loop_link(tmp_path: Path) -> Path:
    (tmp_path / "loop").symlink_to(tmp_path / "loop")
    return tmp_path / "loop"


def a_file(tmp_path: Path) -> Path:
    (tmp_path / "file").write_text("not a folder")
    return tmp_path / "file"


BAD_COMMANDS: dict[str, Callable[[Path], list[str]]] = {
    "runs of a file": lambda t: ["runs", "--runs-dir", str(a_file(t))],
    "runs of /etc/passwd": lambda t: ["runs", "--runs-dir", "/etc/passwd"],
    "runs of a link loop": lambda t: ["runs", "--runs-dir", str(loop_link(t))],
    "runs --json of a file": lambda t: ["runs", "--json", "--runs-dir", str(a_file(t))],
    "train into a file": lambda t: ["train", "cem", "--runs-dir", str(a_file(t)), "--quiet"],
    "train into a link loop": lambda t: ["train", "cem", "--runs-dir", str(loop_link(t)), "--quiet"],
    "train under a file": lambda t: ["train", "cem", "--runs-dir", str(a_file(t) / "runs"), "--quiet"],
    "resume a file": lambda t: ["train", "--resume", str(a_file(t))],
    "resume a link loop": lambda t: ["train", "--resume", str(loop_link(t))],
    "resume with --budget": lambda t: ["train", "--resume", str(t), "--budget", "5"],
    "resume with an empty --budget": lambda t: ["train", "--resume", str(t), "--budget", ""],
    "eval a link loop": lambda t: ["eval", str(loop_link(t))],
    "eval a folder that is no run": lambda t: ["eval", str(t)],
    "eval 10^11 episodes": lambda t: ["eval", str(t), "--episodes", "99999999999"],
    "export a file": lambda t: ["export", str(a_file(t)), "--out", str(t / "x.onnx")],
    "export a link loop": lambda t: ["export", str(loop_link(t)), "--out", str(t / "x.onnx")],
    "export a folder that is no run": lambda t: ["export", str(t), "--out", str(t / "x.onnx")],
    "export to a hub folder that is a file": lambda t: ["export", str(t), "--hub", str(a_file(t))],
    "plot a file": lambda t: ["plot", str(a_file(t)), "--out", str(t / "p.png")],
    "plot a link loop": lambda t: ["plot", str(loop_link(t)), "--out", str(t / "p.png")],
    "plot to .txt": lambda t: ["plot", str(t), "--out", str(t / "p.txt")],
    "version with an extra": lambda t: ["--version", "extra"],
    "version after a command": lambda t: ["runs", "--version"],
    "serve on 256.1.1.1": lambda t: ["serve", "--host", "256.1.1.1", "--runs-dir", str(t)],
    "serve on an empty host": lambda t: ["serve", "--host", "", "--port", "0", "--runs-dir", str(t)],
    "serve on port 70000": lambda t: ["serve", "--port", "70000", "--runs-dir", str(t)],
}


@pytest.mark.parametrize("case", sorted(BAD_COMMANDS))
def test_bad_paths_and_arguments_are_one_line(case, tmp_path, capsys):
    argv = BAD_COMMANDS[case](tmp_path)
    before = fingerprint(tmp_path)
    try:
        code = main(argv)
    except SystemExit as exit:  # argparse's own errors
        code = int(exit.code or 0)
    err = capsys.readouterr().err
    assert_one_line_exit_2(code, err, argv[0] if not argv[0].startswith("-") else "")
    assert fingerprint(tmp_path) == before


# --- runs, plot and the web API list a damaged run and go on ---------------------------------------

WELL_FORMED = ("unknown agent", "unknown env", "seed negative", "setting", "budget")
"""Records of the right shape with a value only a resume can judge: listed as they are."""
LISTED_DAMAGE = {
    name: RESUME_DAMAGE[name]
    for name in RESUME_DAMAGE
    if name.startswith(("config", "status", "eval")) and not any(word in name for word in WELL_FORMED)
} | {
    "latest dangling link": dangling(LATEST),
    "best text": write_text("checkpoints/best.pt", "garbage"),
}


@pytest.mark.parametrize("case", sorted(LISTED_DAMAGE))
def test_one_damaged_run_is_listed_as_unreadable_and_the_others_are_not(case, runs, capsys):
    bad = LISTED_DAMAGE[case](runs)
    good = next(path for path in runs.values() if path != bad)
    runs_dir = bad.parent
    assert main(["runs", "--runs-dir", str(runs_dir), "--json"]) == 0
    listed = {row["name"]: row for row in json.loads(capsys.readouterr().out)}
    assert listed[bad.name]["state"] == "unreadable" and listed[bad.name]["problem"]
    assert listed[good.name]["state"] == "interrupted" and listed[good.name]["problem"] is None

    assert main(["runs", "--runs-dir", str(runs_dir)]) == 0
    table = capsys.readouterr().out
    assert bad.name in table and good.name in table and "unreadable:" in table


def test_plot_skips_an_unreadable_run_with_a_warning(runs, tmp_path, capsys):
    write_text("config.json", "[]")(runs)
    code = main(["plot", str(runs["cem"].parent), "--out", str(tmp_path / "p.png")])
    out, err = capsys.readouterr()
    assert code == 0 and (tmp_path / "p.png").stat().st_size > 0
    assert "1 run, 1 unreadable left out" in out
    assert err.startswith(f"warning: skipped {runs['cem']}: ") and len(err.splitlines()) == 1


def test_the_web_api_lists_an_unreadable_run(runs):
    from conftest_web import local_client

    write_text("status.json", '{"state": 5}')(runs)
    dangling("checkpoints/best.pt", kind="dqn")(runs)
    client = local_client(runs["cem"].parent)
    listed = client.get("/api/runs")
    assert listed.status_code == 200
    rows = {row["name"]: row for row in listed.json()["runs"]}
    assert {row["state"] for row in rows.values()} == {"unreadable"}
    assert "status.json is malformed" in rows[runs["cem"].name]["problem"]
    assert "dangling link" in rows[runs["dqn"].name]["problem"]
    assert str(runs["cem"].parent) not in json.dumps(listed.json()["runs"])
    for name in rows:
        assert client.get(f"/api/runs/{name}").status_code == 200


def test_the_web_api_says_when_the_runs_folder_is_not_one(tmp_path):
    from conftest_web import local_client

    answer = local_client(a_file(tmp_path)).get("/api/runs")
    assert answer.status_code == 200 and answer.json()["runs"] == []
    assert "is not a folder of runs" in answer.json()["problem"]


def test_runs_shows_whole_names_when_piped_and_json_for_scripts(runs, capsys):
    runs_dir = runs["cem"].parent
    assert main(["runs", "--runs-dir", str(runs_dir)]) == 0  # capsys: not a terminal
    table = capsys.readouterr().out
    assert all(path.name in table for path in runs.values()) and "…" not in table
    assert main(["runs", "--runs-dir", str(runs_dir), "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    by_agent = {row["agent"]: row for row in rows}
    cem = by_agent["cem"]
    assert cem["path"] == runs["cem"].name and cem["preset"] == "default" and cem["env_id"] == "CartPole-v1"
    assert cem["seed"] == 0 and cem["state"] == "interrupted" and cem["solved"] is True
    assert cem["env_steps"] > 0 and cem["best_eval_mean"] >= 475
    assert by_agent["dqn"]["solved"] is False


# --- a full disk and a read-only file system ------------------------------------------------------


def fail_with(monkeypatch: pytest.MonkeyPatch, code: int, when: Callable[[str], bool]) -> None:
    """Every os.replace onto a path for which ``when`` holds, and every metrics append, fails with
    ``code``: what a full disk or a read-only mount does to our atomic writes."""
    real_replace = os.replace

    def replace(src, dst, *args, **kwargs):
        if when(str(dst)):
            raise OSError(code, os.strerror(code), str(dst))
        return real_replace(src, dst, *args, **kwargs)

    def append(self, rows):
        if rows:
            raise OSError(code, os.strerror(code), str(self.metrics_path))

    monkeypatch.setattr(os, "replace", replace)
    monkeypatch.setattr(RunDir, "append_metrics", append)


@pytest.mark.parametrize("code", [errno.ENOSPC, errno.EROFS, errno.EACCES, errno.EDQUOT, errno.EIO])
def test_resume_on_a_full_or_read_only_disk_is_one_line_and_loses_nothing(code, runs, monkeypatch, capsys):
    before = fingerprint(runs["cem"].parent)
    fail_with(monkeypatch, code, lambda path: True)
    assert main(["train", "--resume", str(runs["cem"]), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert_one_line_exit_2(2, err, "train")
    assert os.strerror(code) in err and "(" in err  # what went wrong, then what to do
    assert fingerprint(runs["cem"].parent) == before
    assert not list(runs["cem"].rglob(".*.tmp")), "no temp file is left behind"


@pytest.mark.parametrize("code", [errno.EROFS, errno.EACCES])
def test_a_new_run_on_a_read_only_disk_is_one_line(code, tmp_path, monkeypatch, capsys):
    def mkdir(self, *args, **kwargs):
        raise OSError(code, os.strerror(code), str(self))

    monkeypatch.setattr(Path, "mkdir", mkdir)
    assert main(["train", "cem", "--runs-dir", str(tmp_path / "runs"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert_one_line_exit_2(2, err, "train")
    assert os.strerror(code) in err and not (tmp_path / "runs").exists()


def test_a_disk_that_fills_up_mid_run_keeps_the_last_checkpoint(tmp_path, monkeypatch, capsys):
    """The third write of latest.pt (the first is at start) hits a full disk: one line, and the second
    latest.pt still loads and resumes the run to the end of its budget once there is space again."""
    saves = []

    def second_latest(path: str) -> bool:
        if path.endswith("latest.pt"):
            saves.append(path)
        return len(saves) >= 3

    real_replace = os.replace

    def replace(src, dst, *args, **kwargs):
        if str(dst).endswith("latest.pt") and second_latest(str(dst)):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(dst))
        return real_replace(src, dst, *args, **kwargs)

    monkeypatch.setattr(os, "replace", replace)
    argv = ["train", "random-search", "--budget", "6gen", "--no-stop-when-solved", "--quiet"]
    settings_ = ["--set", "population=2", "--set", "checkpoint_every=1", "--set", "eval_every=100000"]
    code = main([*argv, *settings_, "--runs-dir", str(tmp_path / "runs")])
    err = capsys.readouterr().err
    assert_one_line_exit_2(code, err, "train")
    assert "No space left on device" in err and "--resume" in err
    (run,) = (tmp_path / "runs").iterdir()
    kept = load_checkpoint(run / LATEST)
    assert kept.meta["loop"]["iterations"] == 1
    monkeypatch.setattr(os, "replace", real_replace)
    assert main(["train", "--resume", str(run), "--quiet"]) == 0
    assert load_checkpoint(run / LATEST).meta["loop"]["iterations"] == 6


# --- property tests of the parsers -----------------------------------------------------------------

COUNT_UNITS = {"": "env_steps", "k": "env_steps", "ep": "episodes", "gen": "iterations", "it": "iterations"}


@given(st.text(max_size=12))
@settings(max_examples=400, deadline=None)
def test_parse_budget_returns_one_usable_limit_or_refuses(text):
    try:
        budget = parse_budget(text)
    except BudgetError:
        return
    (limit,) = budget.to_dict().items()
    name, value = limit
    if name == "seconds":
        assert 0 < value < float("inf")
    else:
        assert isinstance(value, int) and 1 <= value <= MAX_COUNT


@given(st.integers(min_value=1, max_value=10**9), st.sampled_from(sorted(COUNT_UNITS)))
@settings(max_examples=200, deadline=None)
def test_parse_budget_reads_whole_counts(number, unit):
    scale = 1000 if unit == "k" else 1
    assert parse_budget(f"{number}{unit}") == Budget(**{COUNT_UNITS[unit]: number * scale})


@given(
    st.floats(min_value=0, max_value=1e6, allow_nan=False).filter(lambda x: not x.is_integer()),
    st.sampled_from(["", "ep", "gen"]),
)
@settings(max_examples=200, deadline=None)
def test_parse_budget_refuses_fractional_counts(number, unit):
    with pytest.raises(BudgetError):
        parse_budget(f"{number!r}{unit}")


@given(st.one_of(st.text(max_size=12), st.floats(), st.integers(), st.booleans()))
@settings(max_examples=400, deadline=None)
def test_set_values_become_finite_numbers_of_the_right_kind_or_are_refused(value):
    for key, kind in (("eval_every", int), ("eval_episodes", int)):
        try:
            parsed = getattr(build_config(TrainSettings, {key: value}), key)
        except ConfigError:
            continue
        assert type(parsed) is kind
        assert not isinstance(value, bool)
        assert float(parsed) == float(value if not isinstance(value, str) else value.strip())


@given(st.one_of(st.text(max_size=12), st.floats(), st.integers(min_value=-(10**30), max_value=10**30)))
@settings(max_examples=400, deadline=None)
def test_float_settings_are_always_finite(value):
    from cartpole.agents.dqn.config import DQNConfig

    try:
        parsed = build_config(DQNConfig, {"lr": value}).lr
    except ConfigError:
        return
    assert isinstance(parsed, float) and parsed == parsed and abs(parsed) != float("inf")


@given(st.integers(min_value=-(10**6), max_value=10**6))
def test_whole_numbers_pass_through_set(number):
    assert build_config(TrainSettings, {"eval_every": str(number)}).eval_every == number
