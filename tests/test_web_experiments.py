"""The experiments and sweeps API: reports of `cartpole compare`, Optuna journals of `cartpole sweep`."""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

sys.path.insert(0, str(Path(__file__).parent))
from conftest_web import local_client, make_experiment, make_reported_experiment, make_sweep

EXPERIMENT = "cem-vs-dqn"
SWEEP = "dqn-2seeds"


@pytest.fixture(scope="module")
def runs_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("experiments") / "runs"
    root.mkdir()
    make_experiment(root, EXPERIMENT)
    make_sweep(root, SWEEP)
    return root


@pytest.fixture(scope="module")
def client(runs_dir: Path) -> TestClient:
    return local_client(runs_dir)


def no_machine_path(text: str, runs_dir: Path) -> None:
    assert str(runs_dir.parent) not in text
    assert str(runs_dir.resolve().parent) not in text
    assert "/tmp/" not in text  # the report's run folders were written under /tmp/exp-long


def test_list_has_the_experiment_and_the_sweep(client: TestClient, runs_dir: Path):
    response = client.get("/api/experiments")
    assert response.status_code == 200
    body = response.json()
    [experiment] = body["experiments"]
    assert experiment["name"] == EXPERIMENT and experiment["problem"] is None
    assert experiment["entries"] == ["cem", "dqn", "random-search:tutorial"]
    assert experiment["seeds"] == 10 and experiment["runs"] == 30
    [sweep] = body["sweeps"]
    assert sweep["name"] == SWEEP and sweep["agent"] == "dqn" and sweep["has_best"]
    assert sweep["storage"] == "journal"
    no_machine_path(response.text, runs_dir)


def test_the_runs_list_does_not_take_experiments_for_runs(client: TestClient):
    names = [r["name"] for r in client.get("/api/runs").json()["runs"]]
    assert "experiments" not in names and "sweeps" not in names


def test_experiment_has_counts_cis_and_figures(client: TestClient, runs_dir: Path):
    response = client.get(f"/api/experiments/{EXPERIMENT}")
    assert response.status_code == 200
    body = response.json()
    assert body["problem"] is None
    report = body["report"]
    assert report["env_id"] == "CartPole-v1" and report["confidence"] == 0.95
    cem, dqn, random_search = report["entries"]
    assert (cem["runs"], cem["solved"], cem["final_solved"]) == (10, 10, 10)
    assert random_search["solved"] == 5 and random_search["env_steps_to_solve"]["median_is_lower_bound"]
    low, high = dqn["env_steps_to_solve"]["ci95"]
    assert low <= dqn["env_steps_to_solve"]["median"] <= high
    assert cem["final_mean_return"]["iqm"] == pytest.approx(498.56)
    assert all("/" not in run for run in cem["run_folders"]) and len(cem["run_folders"]) == 10
    assert body["figures"] == ["curves", "solve_steps"]
    assert body["command"][:2] == ["cartpole", "compare"]
    assert body["runs_folder"] == f"experiments/{EXPERIMENT}/runs"
    no_machine_path(response.text, runs_dir)


@pytest.mark.parametrize("figure", ["curves", "solve_steps"])
def test_figures_are_served_as_png(client: TestClient, figure: str):
    response = client.get(f"/api/experiments/{EXPERIMENT}/figures/{figure}.png")
    assert response.status_code == 200
    assert response.headers["content-type"] == "image/png"
    assert response.content.startswith(b"\x89PNG")


@pytest.mark.parametrize(
    "path",
    [
        "/api/experiments/no-such-experiment",
        "/api/experiments/..%2F..%2Fetc",
        "/api/experiments/.hidden",
        "/api/experiments/%2Fetc%2Fpasswd",
        "/api/experiments/" + "x" * 300,
        f"/api/experiments/{EXPERIMENT}/figures/report.png",
        f"/api/experiments/{EXPERIMENT}/figures/..%2Freport.json.png",
        f"/api/experiments/{SWEEP}",
        "/api/sweeps/no-such-sweep",
        "/api/sweeps/..",
        f"/api/sweeps/{EXPERIMENT}",
        "/api/sweeps/no-such-sweep/best.toml",
    ],
)
def test_unknown_or_unsafe_names_are_4xx(client: TestClient, path: str):
    response = client.get(path)
    assert response.status_code in (404, 422), response.text
    assert "/tmp" not in response.text


def test_sweep_has_trials_with_values_states_and_settings(client: TestClient, runs_dir: Path):
    response = client.get(f"/api/sweeps/{SWEEP}")
    assert response.status_code == 200
    body = response.json()
    assert body["problem"] is None
    states = [t["state"] for t in body["trials"]]
    assert states == ["COMPLETE", "PRUNED", "COMPLETE", "FAIL"]
    assert body["counts"] == {"COMPLETE": 2, "PRUNED": 1, "FAIL": 1}
    assert body["best"] == 2
    best = body["trials"][2]
    assert best["value"] == 19800.0 and best["params"] == {"lr": 0.002, "batch_size": 128}
    assert best["seed_costs"] == [18000.0, 21600.0]
    assert best["runs"] == ["CartPole-v1__dqn__s0__20261123-100000", "CartPole-v1__dqn__s1__20261123-100010"]
    assert body["trials"][1]["value"] is None
    assert body["preset"] == "dqn-base.toml"  # a preset file outside the runs folder: its name only
    assert body["dashboard"] == f"optuna-dashboard runs/sweeps/{SWEEP}/journal.log"
    assert "lr = 0.002" in body["best_toml"]
    no_machine_path(response.text, runs_dir)


def test_best_toml_is_served_as_text(client: TestClient):
    response = client.get(f"/api/sweeps/{SWEEP}/best.toml")
    assert response.status_code == 200
    assert response.headers["content-type"].startswith("text/plain")
    assert "batch_size = 128" in response.text


def test_reading_a_sweep_writes_nothing(client: TestClient, runs_dir: Path):
    folder = runs_dir / "sweeps" / SWEEP
    before = {p.name: p.stat().st_mtime_ns for p in folder.iterdir()}
    assert client.get(f"/api/sweeps/{SWEEP}").status_code == 200
    assert {p.name: p.stat().st_mtime_ns for p in folder.iterdir()} == before


def test_a_new_trial_in_the_journal_is_seen(tmp_path: Path):
    import optuna
    from optuna.storages.journal import JournalFileBackend

    make_sweep(tmp_path, SWEEP)
    client = local_client(tmp_path)
    assert len(client.get(f"/api/sweeps/{SWEEP}").json()["trials"]) == 4
    storage = optuna.storages.JournalStorage(
        JournalFileBackend(str(tmp_path / "sweeps" / SWEEP / "journal.log"))
    )
    optuna.load_study(study_name=SWEEP, storage=storage).enqueue_trial({"lr": 1e-3, "batch_size": 40})
    trials = client.get(f"/api/sweeps/{SWEEP}").json()["trials"]
    assert [t["state"] for t in trials][-1] == "WAITING"


# ---------------------------------------------------------------------------------------------------
# Damaged folders: a listed problem (or 4xx), never 5xx
# ---------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "damage, words",
    [
        ("{not json", "report.json is unreadable"),
        ("", "report.json is unreadable"),
        ("[1, 2]", "does not have the form"),
        (json.dumps({"env_id": "CartPole-v1", "entries": [{"entry": "cem"}]}), "does not have the form"),
        ("\udcff", "report.json is unreadable"),
    ],
    ids=["garbage", "empty", "a-list", "fields-missing", "not-utf8"],
)
def test_a_corrupt_report_is_a_listed_problem(tmp_path: Path, damage: str, words: str):
    make_experiment(tmp_path, "broken")
    report = tmp_path / "experiments" / "broken" / "report.json"
    report.write_bytes(damage.encode("utf-8", "surrogateescape"))
    client = local_client(tmp_path)
    listed = client.get("/api/experiments")
    assert listed.status_code == 200
    assert words in listed.json()["experiments"][0]["problem"]
    detail = client.get("/api/experiments/broken")
    assert detail.status_code == 200
    assert detail.json()["report"] is None and words in detail.json()["problem"]
    assert detail.json()["figures"] == ["curves", "solve_steps"]  # what can be shown still is
    assert str(tmp_path) not in detail.text


def test_rliables_figures_and_numbers_are_shown(tmp_path: Path):
    name = make_reported_experiment(tmp_path)
    client = local_client(tmp_path)
    body = client.get(f"/api/experiments/{name}").json()
    assert body["problem"] is None
    assert body["figures"] == ["curves", "solve_steps", "performance_profile", "improvement"]
    assert body["report"]["scores"]["entries"] == ["cem", "dqn"]
    assert body["report"]["scores"]["matrix"][1] == [497.5, 350.0]
    (pair,) = body["report"]["probability_of_improvement"]
    assert (pair["x"], pair["y"]) == ("cem", "dqn") and pair["probability"] == pytest.approx(12 / 16)
    for figure in ("performance_profile", "improvement"):
        png = client.get(f"/api/experiments/{name}/figures/{figure}.png")
        assert png.status_code == 200 and png.content.startswith(b"\x89PNG")


def test_an_experiment_without_its_report_yet_says_so(tmp_path: Path):
    (tmp_path / "experiments" / "running").mkdir(parents=True)
    (tmp_path / "experiments" / "running" / "experiment.json").write_text("{}", "utf-8")
    body = local_client(tmp_path).get("/api/experiments/running").json()
    assert body["report"] is None and body["figures"] == []
    assert "no report.json yet" in body["problem"]
    assert local_client(tmp_path).get("/api/experiments/running/figures/curves.png").status_code == 404


def test_a_symlinked_report_or_figure_is_not_read(tmp_path: Path):
    outside = tmp_path / "elsewhere"
    make_experiment(outside, "real")
    runs = tmp_path / "runs"
    folder = runs / "experiments" / "linked"
    folder.mkdir(parents=True)
    source = outside / "experiments" / "real"
    (folder / "report.json").symlink_to(source / "report.json")
    (folder / "curves.png").symlink_to(source / "curves.png")
    (runs / "experiments" / "whole").symlink_to(source, target_is_directory=True)
    client = local_client(runs)
    body = client.get("/api/experiments/linked").json()
    assert body["report"] is None and body["figures"] == []
    assert client.get("/api/experiments/linked/figures/curves.png").status_code == 404
    assert client.get("/api/experiments/whole").status_code == 404
    assert [e["name"] for e in client.get("/api/experiments").json()["experiments"]] == ["linked"]


@pytest.mark.parametrize(
    "damage",
    ["garbage", "truncated", "missing", "empty", "other-study"],
)
def test_a_damaged_or_missing_journal_is_a_listed_problem(tmp_path: Path, damage: str):
    make_sweep(tmp_path, SWEEP)
    journal = tmp_path / "sweeps" / SWEEP / "journal.log"
    if damage == "garbage":
        journal.write_text("this is not a journal\n{\n", "utf-8")
    elif damage == "truncated":
        journal.write_bytes(journal.read_bytes()[:-40])
    elif damage == "missing":
        journal.unlink()
    elif damage == "empty":
        journal.write_text("", "utf-8")
    else:
        shutil.move(journal, journal.with_name("journal.old"))
        make_sweep(tmp_path / "other", "another")
        shutil.copy(tmp_path / "other" / "sweeps" / "another" / "journal.log", journal)
        make_sweep(tmp_path / "third", "third")
        with journal.open("ab") as out:  # two studies, neither of them this sweep's
            out.write((tmp_path / "third" / "sweeps" / "third" / "journal.log").read_bytes())
    client = local_client(tmp_path)
    response = client.get(f"/api/sweeps/{SWEEP}")
    assert response.status_code == 200, response.text
    body = response.json()
    if damage == "truncated":  # Optuna reads the complete lines; the torn last one is left out
        assert body["problem"] is None or "journal.log" in body["problem"]
    else:
        assert body["problem"] and ("journal.log" in body["problem"])
    assert "lr = 0.002" in body["best_toml"]  # best.toml is still shown
    assert str(tmp_path) not in response.text
    assert client.get("/api/experiments").status_code == 200


def test_a_corrupt_sweep_json_is_a_listed_problem(tmp_path: Path):
    make_sweep(tmp_path, SWEEP)
    (tmp_path / "sweeps" / SWEEP / "sweep.json").write_text("{oops", "utf-8")
    client = local_client(tmp_path)
    [row] = client.get("/api/experiments").json()["sweeps"]
    assert "sweep.json is unreadable" in row["problem"]
    body = client.get(f"/api/sweeps/{SWEEP}").json()
    assert "sweep.json is unreadable" in body["problem"]
    assert len(body["trials"]) == 4  # the journal is still read, under the folder's name


def test_a_database_sweep_is_not_connected_to(tmp_path: Path):
    make_sweep(tmp_path, SWEEP)
    spec_path = tmp_path / "sweeps" / SWEEP / "sweep.json"
    spec = json.loads(spec_path.read_text("utf-8"))
    spec["storage"] = "postgresql://someone:secret@db.example:5432/optuna"
    spec_path.write_text(json.dumps(spec), "utf-8")
    body = local_client(tmp_path).get(f"/api/sweeps/{SWEEP}").json()
    assert body["storage"] == "database" and body["trials"] == []
    assert "optuna-dashboard" in body["problem"]
    assert "secret" not in json.dumps(body)


def test_no_experiments_folder_lists_nothing(tmp_path: Path):
    body = local_client(tmp_path / "not-yet").get("/api/experiments").json()
    assert body == {"experiments": [], "sweeps": []}


def test_pages_are_served(client: TestClient):
    for page in ("/experiments", f"/experiment?name={EXPERIMENT}", f"/sweep?name={SWEEP}"):
        response = client.get(page)
        assert response.status_code == 200 and "<script" in response.text
        assert "content-security-policy" in response.headers


# ---------------------------------------------------------------------------------------------------
# A comparison shared through a database (`cartpole compare --storage`): shown live from the database
# ---------------------------------------------------------------------------------------------------


def finished_record(seed: int, solved: bool) -> dict[str, object]:
    """What a worker stores for one finished run (the fields the report reads)."""
    return {
        "agent": "cem", "preset": "default", "seed": seed, "run": f"/elsewhere/machine{seed}/runs/r{seed}",
        "state": "finished", "solved_in_training": solved, "solve_steps": 1000 if solved else None,
        "solve_wall_seconds": 1.0 if solved else None, "solve_cpu_seconds": 1.5 if solved else None,
        "env_steps": 1000 if solved else 5000, "wall_seconds": 2.0, "cpu_seconds": 3.0,
        "stop_reason": "solved",
        "final_mean": 500.0 if solved else 100.0, "final_solved": solved, "final_verdict": "",
    }  # fmt: skip


def shared_experiment(runs_dir: Path, url: str, name: str = "shared-cmp", finished: int = 1):  # type: ignore[no-untyped-def]
    """A comparison of cem over 3 seeds in the database at ``url``, ``finished`` of them done, and the
    local experiment folder a machine that took part in it keeps (its experiment.json names the storage)."""
    from cartpole.experiments.entries import Entry
    from cartpole.experiments.shared import SharedComparison

    shared = SharedComparison.join(
        url, name, {"env_id": "CartPole-v1", "budget": "3gen"}, [Entry("cem")], [0, 1, 2]
    )
    for seed in range(finished):
        shared.claim("m", 1, {"cem": False}, set(), ["cem"], [seed])
        curve = {
            "steps": [0.0, 500.0, 1000.0],
            "means": [20.0, 200.0, 500.0],
            "solved": True,
            "threshold": 475.0,
        }
        shared.finish("m", Entry("cem"), seed, finished_record(seed, solved=seed % 2 == 0), curve)
    folder = runs_dir / "experiments" / name
    folder.mkdir(parents=True)
    command = ["cartpole", "compare", "cem", "--seeds", "3", "--storage", url, "--name", name]
    setup = {"env_id": "CartPole-v1", "budget": "3gen", "command": command, "storage": url}
    (folder / "experiment.json").write_text(json.dumps(setup), "utf-8")
    return shared


def test_a_shared_comparison_is_shown_live_from_its_database(tmp_path: Path):
    from cartpole.experiments.entries import Entry

    runs_dir = tmp_path / "runs"
    shared = shared_experiment(runs_dir, f"sqlite:///{tmp_path / 'shared.db'}")
    client = local_client(runs_dir)
    body = client.get("/api/experiments/shared-cmp").json()
    assert body["problem"] is None
    assert body["shared"] == {"storage": f"sqlite at {tmp_path / 'shared.db'}", "total": 3, "finished": 1,
                              "running": 0, "pending": 2}  # fmt: skip
    [entry] = body["report"]["entries"]
    assert entry["runs"] == 1 and entry["solved"] == 1 and entry["run_folders"] == ["r0"]
    assert body["figures"] == ["curves", "solve_steps", "performance_profile"]  # one entry: no pairs
    assert body["report"]["scores"]["matrix"] == [[500.0]]
    for figure in body["figures"]:
        png = client.get(f"/api/experiments/shared-cmp/figures/{figure}.png")
        assert png.status_code == 200 and png.content.startswith(b"\x89PNG")
    assert not (runs_dir / "experiments" / "shared-cmp" / "curves.png").exists()  # nothing written there

    shared.claim("m", 1, {"cem": False}, set(), ["cem"], [1])
    shared.finish("m", Entry("cem"), 1, finished_record(1, solved=False), {})
    body = client.get("/api/experiments/shared-cmp").json()
    assert body["shared"]["finished"] == 2
    [entry] = body["report"]["entries"]
    assert entry["runs"] == 2 and entry["solved"] == 1
    [row] = client.get("/api/experiments").json()["experiments"]
    assert row["name"] == "shared-cmp" and row["runs"] == 2 and row["problem"] is None


def test_a_shared_comparison_whose_database_cannot_be_reached_is_a_problem_without_its_password(
    tmp_path: Path,
):
    folder = tmp_path / "experiments" / "gone"
    folder.mkdir(parents=True)
    url = "postgresql://someone:secret@127.0.0.1:1/db"
    (folder / "experiment.json").write_text(
        json.dumps({"env_id": "CartPole-v1", "budget": None, "storage": url})
    )
    client = local_client(tmp_path)
    response = client.get("/api/experiments/gone")
    assert response.status_code == 200
    body = response.json()
    assert body["report"] is None and body["shared"] is None
    assert "cannot read the shared comparison" in body["problem"]
    assert "secret" not in response.text
    assert client.get("/api/experiments/gone/figures/curves.png").status_code == 404


def test_the_web_app_creates_no_database_for_a_shared_comparison(tmp_path: Path):
    """The server only reads: a storage named in experiment.json that is not there stays not there,
    and no tables are made in a database that has none."""
    import sqlite3

    folder = tmp_path / "experiments" / "nowhere"
    folder.mkdir(parents=True)
    missing, empty = tmp_path / "missing.db", tmp_path / "empty.db"
    sqlite3.connect(empty).close()
    for db in (missing, empty):
        setup = {"env_id": "CartPole-v1", "budget": None, "storage": f"sqlite:///{db}"}
        (folder / "experiment.json").write_text(json.dumps(setup), "utf-8")
        body = local_client(tmp_path).get("/api/experiments/nowhere").json()
        assert "cannot read the shared comparison" in body["problem"]
    assert not missing.exists()
    with sqlite3.connect(empty) as connection:
        assert connection.execute("select name from sqlite_master").fetchall() == []
