"""DQN: targets, collection, determinism, checkpoints, presets, config errors, and that it learns."""

from __future__ import annotations

import dataclasses
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest
import torch

from cartpole.agents.dqn import (
    AGENT,
    NUMPY_MAX_WORK,
    DQNConfig,
    DQNLearner,
    Dropout,
    QNetwork,
    policy_from_checkpoint,
    td_targets,
)
from cartpole.agents.presets import preset_names
from cartpole.agents.registry import get_agent
from cartpole.core.errors import ConfigError
from cartpole.envs import env_info
from cartpole.evaluation import ScoredPolicy
from cartpole.runs import Checkpoint, load_checkpoint, save_checkpoint
from cartpole.training import train
from cartpole.training.config import resolve_config

CARTPOLE = env_info("CartPole-v1")
PRESETS = ("default", "tutorial-keras", "tutorial-pytorch")


def small_config(**changes: object) -> DQNConfig:
    """A tiny, quick config for mechanics tests."""
    base = DQNConfig(hidden_sizes=(16, 16), num_envs=3, learning_starts=20, batch_size=8, buffer_size=500)
    return dataclasses.replace(base, **changes)


def flat_params(learner: DQNLearner) -> torch.Tensor:
    return torch.cat([p.detach().flatten() for p in learner.q_net.parameters()])


def stored(learner: DQNLearner, field: str) -> np.ndarray:
    """The written rows of one replay field, as a numpy array."""
    return getattr(learner.buffer, field)[: len(learner.buffer)].cpu().numpy()


# ----------------------------------------------------------------------------------------------
# The Q-network: numpy greedy path against the torch forward
# ----------------------------------------------------------------------------------------------


def torch_q(net: QNetwork, observations: np.ndarray) -> np.ndarray:
    with torch.no_grad():
        return net(torch.from_numpy(observations)).numpy()


@pytest.mark.parametrize("activation", ["relu", "tanh", "elu", "gelu"])
@pytest.mark.parametrize(("dueling", "dropout"), [(False, 0.0), (True, 0.0), (False, 0.3), (True, 0.5)])
def test_numpy_q_values_equal_the_torch_forward(activation: str, dueling: bool, dropout: float) -> None:
    torch.manual_seed(0)
    config = DQNConfig(hidden_sizes=(32, 16), activation=activation, dueling=dueling, dropout=dropout)
    net = QNetwork(4, 3, config).eval()
    for p in net.parameters():  # weights of a trained net's scale, so differences would show
        p.data.normal_(0.0, 0.5)
    rng = np.random.default_rng(0)
    for n in (1, 4, 100, NUMPY_MAX_WORK // (32 * 16) + 1):  # the last one takes the torch path
        observations = rng.normal(scale=2.0, size=(n, 4)).astype(np.float32)
        q = net.q_values(observations)
        assert q.shape == (n, 3) and q.dtype == np.float32
        np.testing.assert_allclose(q, torch_q(net, observations), rtol=1e-5, atol=1e-5)
    assert (net._numpy_plan() is None) == (activation == "gelu")  # numpy has no erf: torch runs it


def test_dropout_zeroes_a_share_p_scales_the_rest_and_is_off_in_eval_mode() -> None:
    torch.manual_seed(0)
    dropout = Dropout(0.3).train()
    x = torch.full((400, 500), 2.0, requires_grad=True)
    y = dropout(x)
    assert abs(float((y == 0).float().mean()) - 0.3) < 0.005
    assert torch.allclose(y[y != 0], torch.tensor(2.0 / 0.7))
    y.sum().backward()
    assert torch.equal(x.grad, (y.detach() / 2.0))  # the gradient goes through the kept units only
    assert torch.equal(dropout.eval()(x), x)


def test_numpy_q_values_follow_in_place_updates_and_copies() -> None:
    learner = DQNLearner(small_config(learning_starts=0), CARTPOLE, seed=4, device="cpu")
    observations = np.random.default_rng(1).normal(size=(5, 4)).astype(np.float32)
    before = learner.q_net.q_values(observations)
    snapshot = learner.policy()
    for _ in range(20):  # optimizer steps update the parameters in place
        learner.learn()
    after = learner.q_net.q_values(observations)
    assert not np.array_equal(before, after)
    np.testing.assert_allclose(after, torch_q(learner.q_net, observations), rtol=1e-5, atol=1e-5)
    np.testing.assert_array_equal(snapshot.scores(observations), before)  # the copy kept its weights
    fresh = QNetwork(4, 2, small_config())
    fresh.load_state_dict(learner.q_net.state_dict(), assign=True)  # new tensors: the cache must see it
    fresh.eval()
    np.testing.assert_allclose(fresh.q_values(observations), after, rtol=1e-6, atol=1e-6)


def test_fused_adam_is_bitwise_torch_adam() -> None:
    fast = DQNLearner(small_config(learning_starts=0), CARTPOLE, seed=5, device="cpu")
    reference = DQNLearner(small_config(learning_starts=0), CARTPOLE, seed=5, device="cpu")
    torch_adam = reference.optimizer.torch_optimizer()  # every step through torch.optim.Adam.step()
    assert isinstance(torch_adam, torch.optim.Adam) and torch_adam.defaults["fused"]
    for _ in range(60):
        fast.learn()
        reference.learn()
    assert fast.gradient_steps > 50
    assert torch.equal(flat_params(fast), flat_params(reference))
    assert all(int(step) == fast.gradient_steps for step in fast.optimizer.steps)
    tensors, _ = fast.optimizer.state_dict()
    torch_state = torch_adam.state_dict()["state"]
    for index, state in torch_state.items():
        for name, value in state.items():
            ours = tensors[f"{index}.{name}"]
            assert torch.equal(ours, value) and ours.dtype == value.dtype


def test_training_never_imports_torch_dynamo() -> None:
    """Any torch.optim optimizer imports torch._dynamo (~1.8 s of CPU); FusedAdam does not need it."""
    code = (
        "import sys; from cartpole.training import train; "
        "train('dqn', seed=0, overrides={'learning_starts': 10, 'buffer_size': 100}, budget='300', "
        "runs_dir=sys.argv[1]); print('torch._dynamo' in sys.modules)"
    )
    with tempfile.TemporaryDirectory() as runs_dir:
        command = [sys.executable, "-c", code, runs_dir]
        out = subprocess.run(command, capture_output=True, text=True, check=True)
    assert out.stdout.strip().splitlines()[-1] == "False"


def test_a_torch_that_refuses_the_direct_adam_call_falls_back_to_torch_optim(monkeypatch) -> None:
    fast = DQNLearner(small_config(learning_starts=0), CARTPOLE, seed=5, device="cpu")
    reference = DQNLearner(small_config(learning_starts=0), CARTPOLE, seed=5, device="cpu")
    for _ in range(5):
        fast.learn()
        reference.learn()
    real, calls = torch._fused_adam_, []

    def refuse_once(*args, **kwargs):  # as if this torch named or shaped the op differently
        calls.append(1)
        if len(calls) == 1:
            raise TypeError("unexpected keyword argument")
        return real(*args, **kwargs)

    monkeypatch.setattr(torch, "_fused_adam_", refuse_once)
    for _ in range(20):
        fast.learn()
        reference.learn()
    assert fast.optimizer._torch_optimizer is not None
    assert torch.equal(flat_params(fast), flat_params(reference))
    assert all(int(step) == fast.gradient_steps for step in fast.optimizer.steps)  # shared state


def test_fused_adam_leaves_a_parameter_without_gradient_alone() -> None:
    learner = DQNLearner(small_config(learning_starts=0), CARTPOLE, seed=5, device="cpu")
    for _ in range(5):
        learner.learn()
    frozen, other = learner.parameters[0], learner.parameters[1]
    before, other_before = frozen.detach().clone(), other.detach().clone()
    for parameter in learner.parameters:
        parameter.grad = torch.ones_like(parameter)
    frozen.grad = None
    learner.optimizer.step()
    assert torch.equal(frozen, before)
    assert not torch.equal(other, other_before)
    assert int(learner.optimizer.steps[0]) == int(learner.optimizer.steps[1]) - 1


# ----------------------------------------------------------------------------------------------
# The Bellman target
# ----------------------------------------------------------------------------------------------


def test_target_bootstraps_at_truncation_but_not_at_termination() -> None:
    rewards = torch.tensor([1.0, 1.0, 1.0])
    terminated = torch.tensor([0.0, 1.0, 0.0])  # row 0: truncated at the time limit; row 2: mid-episode
    next_q = torch.tensor([[10.0, 20.0], [10.0, 20.0], [3.0, 1.0]])
    targets = td_targets(rewards, terminated, next_q, None, gamma=0.5)
    torch.testing.assert_close(targets, torch.tensor([1.0 + 0.5 * 20.0, 1.0, 1.0 + 0.5 * 3.0]))


def test_double_dqn_target_lets_the_online_net_choose_the_action() -> None:
    rewards, terminated = torch.zeros(2), torch.zeros(2)
    next_q_target = torch.tensor([[1.0, 5.0], [7.0, 2.0]])
    next_q_online = torch.tensor([[9.0, 0.0], [0.0, 9.0]])  # picks action 0, then action 1
    targets = td_targets(rewards, terminated, next_q_target, next_q_online, gamma=1.0)
    torch.testing.assert_close(targets, torch.tensor([1.0, 2.0]))


class ScriptedVectorEnv:
    """A 2-env vector env with next-step autoreset: env 0 is truncated at step 3, env 1 terminates
    at step 2. Observations encode (env, episode, step) so stored rows can be traced."""

    def __init__(self) -> None:
        self.steps = np.zeros(2, dtype=np.int64)
        self.episodes = np.zeros(2, dtype=np.int64)
        self.prev_done = np.zeros(2, dtype=bool)
        self.unwrapped = self

    def obs(self) -> np.ndarray:
        rows = [[i, self.episodes[i], self.steps[i], 0.0] for i in range(2)]
        return np.asarray(rows, dtype=np.float32)

    def reset(self, seed: int | None = None) -> tuple[np.ndarray, dict]:
        return self.obs(), {}

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, ...]:
        rewards = np.ones(2, dtype=np.float32)
        terminated, truncated = np.zeros(2, dtype=bool), np.zeros(2, dtype=bool)
        for i in range(2):
            if self.prev_done[i]:  # autoreset step: action ignored, reset observation
                self.episodes[i] += 1
                self.steps[i] = 0
                rewards[i] = 0.0
                continue
            self.steps[i] += 1
            truncated[i] = i == 0 and self.steps[i] == 3
            terminated[i] = i == 1 and self.steps[i] == 2
        self.prev_done = terminated | truncated
        return self.obs(), rewards, terminated, truncated, {}


def test_collection_skips_autoreset_rows_and_keeps_truncation_bootstrappable() -> None:
    learner = DQNLearner(small_config(num_envs=2, learning_starts=10_000), CARTPOLE, seed=0, device="cpu")
    learner.envs = ScriptedVectorEnv()  # type: ignore[assignment]
    learner.observations, _ = learner.envs.reset()
    results = [learner.learn() for _ in range(8)]
    buffer = learner.buffer
    obs, next_obs = stored(learner, "observations"), stored(learner, "next_observations")
    # no stored transition starts from a final state and ends in a reset state
    assert np.all(next_obs[:, 2] == obs[:, 2] + 1)
    assert np.all(next_obs[:, 1] == obs[:, 1])
    # env 0's truncated transitions (step 2 -> 3) are not terminal; env 1's step 1 -> 2 are
    env0_end = (obs[:, 0] == 0) & (next_obs[:, 2] == 3)
    env1_end = (obs[:, 0] == 1) & (next_obs[:, 2] == 2)
    assert env0_end.any() and env1_end.any()
    assert np.all(stored(learner, "terminated")[env0_end] == 0.0)
    assert np.all(stored(learner, "terminated")[env1_end] == 1.0)
    # 8 calls x 2 envs = 16 rows minus the autoreset rows; episodes reported with raw returns
    assert sum(r.env_steps for r in results) == len(buffer) == learner.env_steps
    lengths = sorted(length for r in results for length in r.episode_lengths)
    returns = sorted(ret for r in results for ret in r.episode_returns)
    assert lengths == [2, 2, 2, 3, 3] and returns == [2.0, 2.0, 2.0, 3.0, 3.0]


def test_reward_shaping_changes_stored_rewards_but_not_reported_returns() -> None:
    config = small_config(num_envs=2, learning_starts=10_000, termination_reward=-10.0)
    learner = DQNLearner(config, CARTPOLE, seed=0, device="cpu")
    learner.envs = ScriptedVectorEnv()  # type: ignore[assignment]
    learner.observations, _ = learner.envs.reset()
    results = [learner.learn() for _ in range(8)]
    terminal, rewards = stored(learner, "terminated") == 1.0, stored(learner, "rewards")
    assert np.all(rewards[terminal] == -10.0)
    assert np.all(rewards[~terminal] == 1.0)  # truncation keeps its reward
    assert sorted(ret for r in results for ret in r.episode_returns) == [2.0, 2.0, 2.0, 3.0, 3.0]


def test_short_episode_penalty() -> None:
    config = small_config(
        num_envs=2, learning_starts=10_000, short_episode_reward=-1.0, short_episode_length=3
    )
    learner = DQNLearner(config, CARTPOLE, seed=0, device="cpu")
    learner.envs = ScriptedVectorEnv()  # type: ignore[assignment]
    learner.observations, _ = learner.envs.reset()
    for _ in range(8):
        learner.learn()
    obs, next_obs = stored(learner, "observations"), stored(learner, "next_observations")
    ended_short = (obs[:, 0] == 1) & (next_obs[:, 2] == 2)  # env 1's episodes end at length 2 < 3
    rewards = stored(learner, "rewards")
    assert np.all(rewards[ended_short] == -1.0)
    assert np.all(rewards[~ended_short] == 1.0)  # env 0 ends at 3: not short


# ----------------------------------------------------------------------------------------------
# Determinism, checkpoints, resume
# ----------------------------------------------------------------------------------------------


def test_same_seed_same_result_on_cpu() -> None:
    a = DQNLearner(small_config(), CARTPOLE, seed=7, device="cpu")
    b = DQNLearner(small_config(), CARTPOLE, seed=7, device="cpu")
    returns_a = [r.episode_returns for r in (a.learn() for _ in range(150))]
    returns_b = [r.episode_returns for r in (b.learn() for _ in range(150))]
    assert returns_a == returns_b
    assert a.gradient_steps > 0
    assert torch.equal(flat_params(a), flat_params(b))
    c = DQNLearner(small_config(), CARTPOLE, seed=8, device="cpu")
    for _ in range(150):
        c.learn()
    assert not torch.equal(flat_params(a), flat_params(c))


def test_save_load_gives_the_same_q_values(tmp_path: Path) -> None:
    config = small_config(dueling=True)
    learner = DQNLearner(config, CARTPOLE, seed=1, device="cpu")
    for _ in range(60):
        learner.learn()
    tensors, data = learner.state_dict(resume=False)
    meta = {"agent": "dqn", "env_id": "CartPole-v1", "config": dataclasses.asdict(config), "learner": data}
    save_checkpoint(tmp_path / "best.pt", Checkpoint(meta=meta, tensors=tensors))
    policy = policy_from_checkpoint(load_checkpoint(tmp_path / "best.pt"))
    assert isinstance(policy, ScoredPolicy)
    observations = np.random.default_rng(0).normal(size=(32, 4)).astype(np.float32)
    np.testing.assert_array_equal(policy.scores(observations), learner.policy().scores(observations))
    np.testing.assert_array_equal(policy.act(observations), learner.policy().act(observations))


def test_resume_continues_exactly() -> None:
    config = small_config()
    a = DQNLearner(config, CARTPOLE, seed=3, device="cpu")
    for _ in range(80):
        a.learn()
    tensors, data = a.state_dict(resume=True)
    assert tensors["rng.replay"].dtype == torch.uint8  # the replay sampler's generator state
    b = DQNLearner(config, CARTPOLE, seed=999, device="cpu")  # another seed: everything must be restored
    b.load_state_dict({k: v.clone() for k, v in tensors.items()}, data)
    results_a = [a.learn() for _ in range(80)]
    results_b = [b.learn() for _ in range(80)]
    assert [r.episode_returns for r in results_a] == [r.episode_returns for r in results_b]
    assert [r.scalars for r in results_a] == [r.scalars for r in results_b]
    assert torch.equal(flat_params(a), flat_params(b))


def test_policy_is_a_frozen_snapshot() -> None:
    learner = DQNLearner(small_config(learning_starts=0), CARTPOLE, seed=2, device="cpu")
    policy = learner.policy()
    observations = np.zeros((4, 4), dtype=np.float32)
    before = policy.scores(observations)
    for _ in range(30):
        learner.learn()
    np.testing.assert_array_equal(policy.scores(observations), before)


# ----------------------------------------------------------------------------------------------
# Presets and config errors
# ----------------------------------------------------------------------------------------------


def test_registered() -> None:
    assert get_agent("dqn") is AGENT
    assert set(PRESETS) <= set(preset_names("dqn"))


@pytest.mark.parametrize("preset", PRESETS)
def test_each_preset_loads_and_runs_a_few_steps(preset: str) -> None:
    config, settings = resolve_config("dqn", DQNConfig, preset)
    config = dataclasses.replace(config, learning_starts=min(config.learning_starts, 10))
    learner = DQNLearner(config, CARTPOLE, seed=0, device="cpu")
    for _ in range(40):
        result = learner.learn()
    assert learner.gradient_steps > 0
    assert np.isfinite(result.scalars["train/loss"])
    assert 0.0 <= result.scalars["train/epsilon"] <= 1.0
    assert settings.budget


def test_tutorial_presets_are_faithful() -> None:
    keras, keras_settings = resolve_config("dqn", DQNConfig, "tutorial-keras")
    assert keras.hidden_sizes == (512, 256, 64) and keras.dropout == 0.5
    assert (keras.buffer_size, keras.batch_size, keras.gamma) == (2000, 128, 0.95)
    assert keras.epsilon_schedule == "multiplicative" and keras.termination_reward == -10.0
    assert keras_settings.budget == "1000ep"
    torch_cfg, torch_settings = resolve_config("dqn", DQNConfig, "tutorial-pytorch")
    assert torch_cfg.hidden_sizes == (256,)
    assert (torch_cfg.buffer_size, torch_cfg.batch_size, torch_cfg.gamma, torch_cfg.lr) == (
        10_000,
        512,
        0.8,
        1e-3,
    )
    assert torch_cfg.epsilon_schedule == "exponential" and torch_cfg.epsilon_decay_steps == 200
    assert (torch_cfg.short_episode_reward, torch_cfg.short_episode_length) == (-1.0, 195)
    assert torch_settings.budget == "100ep"


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        ({"lr": "-0.001"}, "lr must be > 0"),
        ({"batch_size": "0"}, "batch_size must be >= 1"),
        ({"gamma": "1.5"}, "gamma must be in"),
        ({"loss": "l3"}, "loss must be one of"),
        ({"epsilon_schedule": "cosine"}, "epsilon_schedule must be one of"),
        ({"hidden_sizes": "64,0"}, "hidden_sizes must all be >= 1"),
        ({"no_such_knob": "1"}, "unknown setting 'no_such_knob'"),
        ({"lr": "fast"}, "lr='fast' is not a valid"),
    ],
)
def test_bad_config_values_are_rejected_with_one_line(overrides: dict[str, str], message: str) -> None:
    with pytest.raises(ConfigError, match=message) as info:
        resolve_config("dqn", DQNConfig, "default", overrides)
    assert "\n" not in str(info.value)


def test_unknown_preset_is_rejected_with_one_line() -> None:
    with pytest.raises(ConfigError, match="unknown preset 'nope'") as info:
        resolve_config("dqn", DQNConfig, "nope")
    assert "\n" not in str(info.value)


# ----------------------------------------------------------------------------------------------
# It learns
# ----------------------------------------------------------------------------------------------


def test_default_preset_reaches_a_verified_solve(tmp_path: Path) -> None:
    outcome = train("dqn", "CartPole-v1", seed=0, runs_dir=tmp_path, device="cpu", quiet=True)
    assert outcome.state.solved, outcome.state.stop_reason
    assert outcome.state.solved_at_step is not None and outcome.state.solved_at_step <= 50_000
    assert outcome.report is not None and outcome.report.solved, outcome.report and outcome.report.verdict
    # the run folder's best checkpoint loads back as a policy on CPU and is the one judged
    assert (outcome.run.checkpoint_path("best")).is_file()


def test_acrobot_return_improves() -> None:
    """Unchanged code on another Box/Discrete env: Acrobot-v1's training return rises from ~-450."""
    overrides = {"epsilon_decay_steps": "3000", "batch_size": "128"}
    config, _ = resolve_config("dqn", DQNConfig, "default", overrides)
    learner = DQNLearner(config, env_info("Acrobot-v1"), seed=0, device="cpu")
    returns: list[float] = []
    while learner.env_steps < 10_000:
        returns += learner.learn().episode_returns
    first, last = float(np.mean(returns[:10])), float(np.mean(returns[-10:]))
    assert last > first + 150 and last > -300, (first, last)


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(1, 6))
def test_default_preset_solves_more_seeds(tmp_path: Path, seed: int) -> None:
    outcome = train("dqn", "CartPole-v1", seed=seed, runs_dir=tmp_path, device="cpu", quiet=True)
    assert outcome.report is not None and outcome.report.solved, outcome.report and outcome.report.verdict
