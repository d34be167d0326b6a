"""``cartpole export``: a saved agent's greedy policy as ONNX that acts as ours does under
onnxruntime (every agent on CartPole-v1, DQN and PPO on pixels), and a model hub folder that loads
back, whose card's metadata parses."""

from __future__ import annotations

import builtins
import json
import shlex
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import cartpole
from cartpole.agents.registry import open_policy
from cartpole.cli.main import main
from cartpole.export import NEAR_TIE, PARITY_OBSERVATIONS, check_parity, play_observations, write_onnx
from cartpole.training import train

onnxruntime = pytest.importorskip("onnxruntime")
yaml = pytest.importorskip("yaml")

PIXELS = "cartpole/CartPolePixels-v1"
STANDARDIZED = {"observation_mean": (0.1, -0.2, 0.02, 0.1), "observation_std": (0.2, 0.5, 0.03, 0.4)}

RUNS: dict[str, tuple[str, str, str | None, str, dict[str, Any]]] = {
    # case: (agent, env, preset, budget, settings)
    "random-search": ("random-search", "CartPole-v1", None, "2gen", {}),
    "hill-climbing": ("hill-climbing", "CartPole-v1", None, "2gen", {}),
    "cem": ("cem", "CartPole-v1", None, "2gen", {}),
    "cem-scaled-bias": ("cem", "CartPole-v1", None, "2gen", {"normalize_observations": True, "bias": True}),
    "dqn": ("dqn", "CartPole-v1", None, "2000", {}),
    "dqn-dueling-dropout": ("dqn", "CartPole-v1", None, "2000", {"dueling": True, "dropout": 0.2}),
    "reinforce": ("reinforce", "CartPole-v1", None, "2000", {}),
    "a2c": ("a2c", "CartPole-v1", None, "2000", {}),
    "ppo": ("ppo", "CartPole-v1", None, "2048", {}),
    "ppo-standardized": ("ppo", "CartPole-v1", None, "2048", STANDARDIZED),
    "ppo-pixels": (
        "ppo",
        PIXELS,
        "pixels",
        "512",
        {"n_steps": 16, "num_envs": 4, "minibatch_size": 64, "eval_every": 100_000},
    ),
    "dqn-pixels": (
        "dqn",
        PIXELS,
        "pixels",
        "300",
        {"buffer_size": 1_000, "batch_size": 32, "frame_difference": True, "eval_every": 100_000},
    ),
}


def trained(case: str, runs_dir: Path) -> Path:
    agent, env_id, preset, budget, settings = RUNS[case]
    outcome = train(
        agent, env_id, seed=3, preset=preset, overrides=settings, budget=budget, runs_dir=runs_dir
    )
    return outcome.run.path


@pytest.mark.parametrize("case", list(RUNS))
def test_onnx_acts_as_ours_wherever_our_two_best_scores_do_not_nearly_tie(case, tmp_path, capsys):
    run = trained(case, tmp_path / "runs")
    opened = open_policy(run)
    graph = write_onnx(opened, tmp_path / "policy.onnx")
    count = PARITY_OBSERVATIONS
    observations = play_observations(opened.policy, opened.env, count, seed=5)
    assert observations.shape == (count, *opened.env.obs_shape)
    parity = check_parity(opened, graph, observations)
    with capsys.disabled():
        print(f"\n{case}: {parity.summary()}")
    assert parity.equal, parity.summary()
    assert parity.observations == count and parity.compared >= 0.99 * count  # near-ties are rare

    session = onnxruntime.InferenceSession(str(graph), providers=["CPUExecutionProvider"])
    assert [i.name for i in session.get_inputs()] == ["observations"]
    action, scores = session.run(["action", "scores"], {"observations": observations[:500]})
    assert action.dtype == np.int64 and scores.shape == (500, opened.env.n_actions)
    assert np.array_equal(action, scores.argmax(axis=1))
    (one,) = session.run(["action"], {"observations": observations[:1]})  # any batch size
    assert one.tolist() == action[:1].tolist()
    if opened.checkpoint.agent != "dqn" and hasattr(opened.policy, "params"):  # linear: [-s, s]
        assert np.allclose(scores, opened.policy.scores(observations[:500]), rtol=1e-5, atol=1e-5)
    if opened.checkpoint.agent == "dqn":  # Q-values
        assert np.allclose(scores, opened.policy.scores(observations[:500]), rtol=1e-4, atol=1e-4)
    meta = session.get_modelmeta().custom_metadata_map
    assert (meta["agent"], meta["env_id"], meta["seed"]) == (RUNS[case][0], RUNS[case][1], "3")
    assert meta["step"] == str(opened.checkpoint.meta["step"])


def test_the_graph_holds_the_standardization(tmp_path):
    """The same weights without their standardization act otherwise: the parity above needs it."""
    run = trained("ppo-standardized", tmp_path / "runs")
    opened = open_policy(run)
    graph = write_onnx(opened, tmp_path / "policy.onnx")
    observations = play_observations(opened.policy, opened.env, 2_000, seed=5)
    session = onnxruntime.InferenceSession(str(graph), providers=["CPUExecutionProvider"])
    (action,) = session.run(["action"], {"observations": observations})
    assert np.array_equal(action, opened.policy.act(observations))
    mean, std = (
        np.asarray(STANDARDIZED[k], dtype=np.float32) for k in ("observation_mean", "observation_std")
    )
    (unscaled,) = session.run(["action"], {"observations": (observations - mean) / std})
    assert not np.array_equal(unscaled, action)  # standardizing twice changes the actions


def test_played_observations_follow_the_seed(cem_run):
    opened = open_policy(cem_run)
    first = play_observations(opened.policy, opened.env, 300, seed=1)
    assert np.array_equal(first, play_observations(opened.policy, opened.env, 300, seed=1))
    assert not np.array_equal(first, play_observations(opened.policy, opened.env, 300, seed=2))


# --- the command --------------------------------------------------------------------------------


def test_export_writes_the_run_named_onnx_file_here_and_checks_it(cem_run, tmp_path, monkeypatch, capsys):
    before = sorted(str(p.relative_to(cem_run)) for p in cem_run.rglob("*"))
    monkeypatch.chdir(tmp_path)
    assert main(["export", str(cem_run), "--format", "onnx"]) == 0
    out = capsys.readouterr().out
    written = tmp_path / f"{cem_run.name}.onnx"
    assert written.is_file() and f"wrote {written.name}" in out
    assert f"of {PARITY_OBSERVATIONS:,} observations (0 near-ties" in out or "near-ties" in out
    assert "actions equal on" in out and f"near-ties within {NEAR_TIE:g} not compared" in out
    assert sorted(str(p.relative_to(cem_run)) for p in cem_run.rglob("*")) == before  # only read


def test_export_out_names_the_file(cem_run, tmp_path, capsys):
    out = tmp_path / "deep" / "cem.onnx"
    assert main(["export", str(cem_run / "checkpoints" / "best.pt"), "--out", str(out)]) == 0
    assert out.is_file() and f"wrote {out}" in capsys.readouterr().out
    session = onnxruntime.InferenceSession(str(out), providers=["CPUExecutionProvider"])
    assert session.get_modelmeta().custom_metadata_map["agent"] == "cem"


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--out", "policy.pt"], "name an .onnx file"),
        (["--out", "x.onnx", "--hub", "hub"], "drop --out"),
    ],
)
def test_export_bad_flags_are_one_line(cem_run, tmp_path, monkeypatch, capsys, args, message):
    monkeypatch.chdir(tmp_path)
    assert main(["export", str(cem_run), *args]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1 and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []


def test_export_knows_one_format(cem_run, capsys):
    with pytest.raises(SystemExit) as exit:
        main(["export", str(cem_run), "--format", "tflite"])
    assert exit.value.code == 2 and "invalid choice: 'tflite'" in capsys.readouterr().err


def test_export_without_the_extra_names_it(cem_run, tmp_path, monkeypatch, capsys):
    real_import = builtins.__import__

    def no_onnx(name: str, *args: Any, **kwargs: Any) -> Any:
        if name.startswith("onnx"):
            raise ImportError(name, name=name)
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_onnx)
    out = tmp_path / "cem.onnx"
    assert main(["export", str(cem_run), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert 'pip install -e ".[export]"' in err and err.count("\n") == 1 and "Traceback" not in err
    assert not out.exists()


def test_export_of_a_run_without_a_checkpoint_is_one_line(cem_run, tmp_path, capsys):
    run = tmp_path / cem_run.name
    run.mkdir()
    shutil.copyfile(cem_run / "config.json", run / "config.json")
    assert main(["export", str(run), "--out", str(tmp_path / "x.onnx")]) == 2
    err = capsys.readouterr().err
    assert "has no checkpoint yet" in err and err.count("\n") == 1
    assert main(["export", str(run), "--hub", str(tmp_path / "hub")]) == 2
    assert "no verdict yet" in capsys.readouterr().err and not (tmp_path / "hub").exists()


# --- the model hub folder -----------------------------------------------------------------------


def front_matter(card: str) -> dict[str, Any]:
    """The YAML between the card's first two ``---`` lines, as the hub reads it."""
    assert card.startswith("---\n")
    return yaml.safe_load(card.split("---\n")[1])


def test_hub_folder_loads_back_and_its_card_carries_the_verdict(cem_run, tmp_path, capsys):
    pytest.importorskip("imageio_ffmpeg")
    hub = tmp_path / "hub" / "cem-CartPole-v1"
    assert main(["export", str(cem_run), "--hub", str(hub)]) == 0
    out = capsys.readouterr().out
    assert f"hf upload USER/REPO {hub} ." in out and "actions equal" in out
    names = sorted(str(p.relative_to(hub)) for p in hub.rglob("*"))
    assert names == sorted(
        [
            "README.md",
            "checkpoints",
            "checkpoints/best.pt",
            "config.json",
            "eval.json",
            "model.onnx",
            "replay.mp4",
        ]
    )
    assert [p.name for p in hub.parent.iterdir()] == [hub.name]  # no staging folder left
    assert (hub / "replay.mp4").read_bytes()[4:8] == b"ftyp"
    assert (hub / "checkpoints" / "best.pt").read_bytes() == (
        cem_run / "checkpoints" / "best.pt"
    ).read_bytes()

    verdict = json.loads((cem_run / "eval.json").read_text())
    assert json.loads((hub / "eval.json").read_text()) == verdict
    config = json.loads((hub / "config.json").read_text())
    card = (hub / "README.md").read_text()
    meta = front_matter(card)
    assert meta["library_name"] == "cartpole"
    assert {"reinforcement-learning", "CartPole-v1", "cem"} <= set(meta["tags"])
    (model,) = meta["model-index"]
    assert model["name"] == "cem-CartPole-v1"
    (result,) = model["results"]
    assert result["task"]["type"] == "reinforcement-learning"
    assert result["dataset"]["name"] == "CartPole-v1"
    (metric,) = result["metrics"]
    mean, std = np.mean(verdict["returns"]), np.std(verdict["returns"])
    assert metric["type"] == "mean_reward" and metric["value"] == f"{mean:.2f} +/- {std:.2f}"
    assert shlex.join(config["command"]) in card and "SOLVED" in card and "replay.mp4" in card
    assert "cartpole.load_policy" in card and "onnxruntime" in card

    observations = play_observations(cartpole.load_policy(str(cem_run)), open_policy(cem_run).env, 500)
    ours = cartpole.load_policy(str(cem_run)).act(observations)
    assert np.array_equal(cartpole.load_policy(str(hub)).act(observations), ours)
    assert main(["eval", str(hub), "--episodes", "3", "--seed", "7", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["checkpoint"] == str(hub / "checkpoints" / "best.pt") and report["episodes"] == 3


def test_hub_folder_without_the_video_extra_says_so(cem_run, tmp_path, monkeypatch, capsys):
    real_import = builtins.__import__

    def no_ffmpeg(name: str, *args: Any, **kwargs: Any) -> Any:
        if name.startswith("imageio"):
            raise ImportError(name)
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_ffmpeg)
    hub = tmp_path / "hub"
    hub.mkdir()  # an empty folder is fine
    assert main(["export", str(cem_run), "--hub", str(hub)]) == 0
    assert "no replay video" in capsys.readouterr().out
    assert not (hub / "replay.mp4").exists() and (hub / "model.onnx").is_file()
    assert "No replay" in (hub / "README.md").read_text()


def test_hub_refuses_a_folder_that_is_not_empty_a_file_and_a_checkpoint(cem_run, tmp_path, capsys):
    hub = tmp_path / "hub"
    hub.mkdir()
    (hub / "mine.txt").write_text("keep me")
    assert main(["export", str(cem_run), "--hub", str(hub)]) == 2
    err = capsys.readouterr().err
    assert f"--hub {hub} is not empty" in err and err.count("\n") == 1
    assert [p.name for p in hub.iterdir()] == ["mine.txt"]
    assert main(["export", str(cem_run), "--hub", str(hub / "mine.txt")]) == 2
    assert "is a file" in capsys.readouterr().err
    assert main(["export", str(cem_run / "checkpoints" / "best.pt"), "--hub", str(tmp_path / "new")]) == 2
    assert "give the run's folder" in capsys.readouterr().err and not (tmp_path / "new").exists()


def test_a_failed_hub_export_leaves_nothing(cem_run, tmp_path, monkeypatch, capsys):
    import cartpole.export.hub

    def full_disk(*args: Any) -> None:
        raise OSError(28, "No space left on device", "model.onnx")

    monkeypatch.setattr(cartpole.export.hub, "write_onnx", full_disk)
    assert main(["export", str(cem_run), "--hub", str(tmp_path / "hub")]) == 2
    assert "No space left on device" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []  # neither the folder nor its staging folder


def test_the_card_of_a_changed_env_names_its_kwargs(tmp_path, capsys):
    outcome = train(
        "cem", "CartPole-v1", seed=0, overrides={"env_kwargs": {"gravity": 5.0}}, budget="2gen",
        runs_dir=tmp_path / "runs", quiet=True,
    )  # fmt: skip
    hub = tmp_path / "hub"
    assert main(["export", str(outcome.run.path), "--hub", str(hub)]) == 0
    card = (hub / "README.md").read_text()
    (result,) = front_matter(card)["model-index"][0]["results"]
    assert result["dataset"] == {"name": "CartPole-v1 (gravity=5.0)", "type": "CartPole-v1"}
    assert "# cem on CartPole-v1 (gravity=5.0)" in card
