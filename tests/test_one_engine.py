"""One engine for every run: every run trains as a population, a single run (``--seed N``) being a
population of one, and seed N trains bit for bit the same alone as beside other seeds, for every
agent, on every env."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
import torch

from cartpole.agents.registry import agent_names, build_population, get_agent
from cartpole.cli.main import main
from cartpole.envs import env_info
from cartpole.training import train
from cartpole.training.config import resolve_config
from cartpole.training.session import train_population

SMALL = {
    "ppo": ({"n_steps": 16, "num_envs": 4, "minibatch_size": 32, "hidden_sizes": "16,16"}, "3k"),
    "a2c": ({"n_steps": 8, "num_envs": 4, "hidden_sizes": "16,16"}, "3k"),
    "reinforce": ({"num_envs": 2, "hidden_sizes": "16,16"}, "3k"),
    "dqn": ({"hidden_sizes": "16,16", "learning_starts": "200", "batch_size": "32"}, "2k"),
    "cem": ({"population": "8"}, "3gen"),
    "random-search": ({"population": "8"}, "3gen"),
    "hill-climbing": ({"population": "8"}, "3gen"),
}
"""Per agent: small settings and a budget that trains a few updates and evaluates on the way."""

NEURAL = ("ppo", "a2c", "reinforce", "dqn")
"""The agents whose arithmetic runs on torch's and MKL's kernels (the linear searches' is NumPy's)."""


def marked(cases: list[Any]) -> list[Any]:
    """``cases`` (an agent, or a tuple starting with one) as parameters, the neural agents' marked
    ``independence``: CI runs those again under MKL's AVX2 and SSE4.2 paths."""
    params = []
    for case in cases:
        values = case if isinstance(case, tuple) else (case,)
        params.append(pytest.param(*values, marks=pytest.mark.independence if values[0] in NEURAL else ()))
    return params


def test_every_agent_is_covered():
    assert set(SMALL) == set(agent_names())


def run_files(run: Path, idle: tuple[str, ...]) -> dict[str, Any]:
    """What a run left that must not depend on its neighbours: metric rows (without wall times),
    the verdict, and every tensor of its latest and best checkpoints but one: REINFORCE plays until
    the longest episode of its batch ends, so a seed's finished envs step on idle until then, and
    where they stand (``collector.*``) is never used: every batch restarts them."""
    rows = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
    rows = [{k: v for k, v in row.items() if k not in ("time", "time/sps")} for row in rows]
    files: dict[str, Any] = {"metrics": rows, "verdict": json.loads((run / "eval.json").read_text())}
    for name in ("latest", "best"):
        tensors = torch.load(run / "checkpoints" / f"{name}.pt", weights_only=True)["tensors"]
        files[name] = {k: v for k, v in tensors.items() if not k.startswith(idle)}
    return files


def assert_same_run(a: Path, b: Path, agent: str) -> None:
    idle = ("collector.",) if agent == "reinforce" else ()
    left, right = run_files(a, idle), run_files(b, idle)
    assert left["metrics"] == right["metrics"]
    assert left["verdict"] == right["verdict"]
    for name in ("latest", "best"):
        assert left[name].keys() == right[name].keys()
        for key, tensor in left[name].items():
            assert torch.equal(tensor, right[name][key]), f"{name}.pt: {key} differs"


@pytest.mark.parametrize("agent", marked(sorted(SMALL)))
def test_seed_alone_is_bit_identical_to_the_seed_in_a_population(agent, tmp_path):
    overrides, budget = SMALL[agent]
    options = {"overrides": dict(overrides), "budget": budget, "stop_when_solved": False}
    alone = train_population(agent, [4], runs_dir=tmp_path / "alone", **options)
    among = train_population(agent, [9, 4, 2], runs_dir=tmp_path / "among", **options)
    assert alone.states[4].env_steps == among.states[4].env_steps > 0
    assert alone.states[4].evaluations >= 1
    assert_same_run(alone.runs[4].path, among.runs[4].path, agent)


@pytest.mark.parametrize("agent", marked(sorted(SMALL)))
def test_a_single_run_is_its_seed_in_a_population(agent, tmp_path):
    """``cartpole train AGENT --seed 4`` and ``--seeds 9,4``: the same run of seed 4, bit for bit."""
    overrides, budget = SMALL[agent]
    options = {"overrides": dict(overrides), "budget": budget, "stop_when_solved": False}
    single = train(agent, seed=4, runs_dir=tmp_path / "single", **options)
    among = train_population(agent, [9, 4], runs_dir=tmp_path / "among", **options)
    assert single.state.env_steps == among.states[4].env_steps > 0
    assert_same_run(single.run.path, among.runs[4].path, agent)


OTHER_ENVS = [
    ("ppo", "Acrobot-v1", "default"),
    ("a2c", "MountainCar-v0", "default"),
    ("ppo", "MountainCar-v0", "mountaincar"),  # observations standardized
    ("reinforce", "Acrobot-v1", "default"),
    ("dqn", "Acrobot-v1", "default"),
    ("dqn", "CartPole-v1", "tutorial-pytorch"),
    ("cem", "Acrobot-v1", "default"),
]
"""Envs and simulators of Gymnasium's own (each seed's vector env stepped in turn), one per agent."""


@pytest.mark.parametrize(("agent", "env_id", "preset"), marked(OTHER_ENVS))
def test_other_envs_batch_with_the_same_independence(agent, env_id, preset, tmp_path):
    """On Gymnasium's envs too, seed N alone is bit for bit seed N among others."""
    overrides = SMALL[agent][0]
    budget = "2gen" if agent == "cem" else "600" if preset.startswith("tutorial") else "1500"
    options = {"overrides": dict(overrides), "budget": budget, "preset": preset, "stop_when_solved": False}
    alone = train_population(agent, [2], env_id, runs_dir=tmp_path / "alone", **options)
    among = train_population(agent, [1, 2], env_id, runs_dir=tmp_path / "among", **options)
    assert alone.states[2].env_steps == among.states[2].env_steps > 0
    assert_same_run(alone.runs[2].path, among.runs[2].path, agent)


@pytest.mark.independence
def test_the_tutorial_presets_on_gymnasiums_env_train_as_populations_too(tmp_path, capsys):
    code = main(
        ["train", "dqn", "--preset", "tutorial-pytorch", "--seeds", "0,1", "--budget", "600",
         "--runs-dir", str(tmp_path), "--quiet"]
    )  # fmt: skip
    assert code == 0
    assert "2 runs in" in capsys.readouterr().out
    assert len(list(tmp_path.iterdir())) == 2


@pytest.mark.independence
@pytest.mark.parametrize(
    ("agent", "env_id", "preset"),
    [
        ("ppo", "Acrobot-v1", "default"),
        ("reinforce", "MountainCar-v0", "default"),
        ("dqn", "MountainCar-v0", "default"),
        ("dqn", "CartPole-v1", "tutorial-keras"),
    ],
)
def test_a_seed_on_gymnasiums_envs_resumes_mid_episode_exactly(agent, env_id, preset):
    """A seed's checkpoint (through JSON, as on disk) holds its Gymnasium envs mid-episode: resumed
    beside another seed, it goes on exactly as without the break."""
    spec = get_agent(agent)
    config, _ = resolve_config(agent, spec.config_cls, preset, dict(SMALL[agent][0]))
    env = env_info(env_id)
    straight = build_population(spec, config, env, [3, 5])
    calls = 40 if agent == "dqn" else 3
    for _ in range(calls):
        straight.learn()
    tensors, data = straight.seed_state_dict(3, resume=True)
    resumed = build_population(spec, config, env, [7, 3])
    resumed.load_seed_state_dict(3, tensors, json.loads(json.dumps(data)))
    for _ in range(calls):
        assert straight.learn()[3] == resumed.learn()[3]
    after, _ = straight.seed_state_dict(3, resume=True)
    again, _ = resumed.seed_state_dict(3, resume=True)
    assert after.keys() == again.keys()
    for key, tensor in after.items():
        assert torch.equal(tensor, again[key]), key


NEURAL_AGENTS = ["a2c", "dqn", "ppo", "reinforce"]


@pytest.mark.parametrize("env_id", ["CartPole-v1", "Acrobot-v1"])
@pytest.mark.parametrize("agent", NEURAL_AGENTS)
def test_with_two_threads_a_seed_alone_is_still_the_seed_in_a_population(agent, env_id):
    """On two torch threads (``--torch-threads 2``; a pixel env's default, every core) torch gives a
    lone seed's products to a threaded single matrix product and several seeds' to a batched one:
    the seed must still train bit for bit the same alone as among others. Acrobot's 6 inputs tell
    the two apart on any CPU, CartPole's 4 on CPUs without AVX-512 (run with ``MKL_CBWR=AVX2``)."""
    torch.set_num_threads(2)  # the autouse fixture sets one thread again for the next test
    spec = get_agent(agent)
    config, _ = resolve_config(agent, spec.config_cls, "default", dict(SMALL[agent][0]))
    env = env_info(env_id)
    alone = build_population(spec, config, env, [3])
    among = build_population(spec, config, env, [5, 3, 8])
    for _ in range(30 if agent == "dqn" else 3):  # DQN: past its learning_starts
        assert alone.learn()[3] == among.learn()[3]
    idle = ("collector.",) if agent == "reinforce" else ()  # see run_files
    tensors, _ = alone.seed_state_dict(3, resume=True)
    others, _ = among.seed_state_dict(3, resume=True)
    assert tensors.keys() == others.keys()
    for key, tensor in tensors.items():
        assert key.startswith(idle) or torch.equal(tensor, others[key]), key
