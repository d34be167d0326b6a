"""Deep Q-Network (DQN) in PyTorch, readable top to bottom.

What it does, in order:

1. ``DQNConfig``: every knob, with a one-line docstring each (presets in ``presets/dqn.toml``).
2. ``QNetwork``: an MLP Q-network (optional dropout, optional dueling head).
3. ``td_targets``: the one place the Bellman target is computed (double DQN, and no bootstrap at
   termination; truncation by the time limit does bootstrap).
4. ``DQNLearner``: collects one batched step from ``num_envs`` vector envs per ``learn()`` call with a
   single forward pass, stores it in the shared :class:`~cartpole.agents.replay_buffer.ReplayBuffer`,
   and runs ``gradient_steps`` updates every ``train_freq`` calls. The shared training loop does the
   rest (evaluation, best checkpoint, stop when solved, budget).
5. ``QNetworkPolicy``: the greedy policy, from a learner or a checkpoint.

The three exploration schedules are the ones the tutorials used: linear (ours), exponential per env
step (the PyTorch tutorial), and multiplicative per gradient step (the Keras tutorial).
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from cartpole.agents.adam import FusedAdam
from cartpole.agents.learner import LearnResult
from cartpole.agents.memory import dqn_memory_problem
from cartpole.agents.registry import AgentSpec
from cartpole.agents.replay_buffer import ReplayBuffer
from cartpole.core.config import build_config, require
from cartpole.envs import EnvInfo, check_simulator, make_vec_env
from cartpole.runs import Checkpoint, CheckpointError

ACTIVATIONS: dict[str, type[nn.Module]] = {"relu": nn.ReLU, "tanh": nn.Tanh, "elu": nn.ELU, "gelu": nn.GELU}
SCHEDULES = ("linear", "exponential", "multiplicative")
LOSSES = ("huber", "mse")


# ----------------------------------------------------------------------------------------------
# 1. Configuration
# ----------------------------------------------------------------------------------------------


def seed_everything(seed: int) -> np.random.Generator:
    """Seed torch's and Python's global generators; return a numpy Generator for the caller."""
    import random

    random.seed(seed)
    torch.manual_seed(seed)
    return np.random.default_rng(seed)


@dataclass
class DQNConfig:
    """Hyperparameters of DQN. Defaults are the ``default`` preset's values for CartPole-v1."""

    # network
    hidden_sizes: tuple[int, ...] = (64, 64)
    """Widths of the hidden layers of the Q-network MLP."""
    activation: str = "relu"
    """Hidden-layer activation: relu, tanh, elu or gelu."""
    dropout: float = 0.0
    """Dropout after each hidden layer while training (0 = none); acting and targets run without it."""
    dueling: bool = False
    """Dueling head: Q = V + A - mean(A)."""
    # learning
    lr: float = 1e-3
    """Adam learning rate."""
    gamma: float = 0.99
    """Discount factor."""
    loss: str = "huber"
    """TD loss: huber (smooth L1) or mse."""
    max_grad_norm: float | None = None
    """Clip the gradient's global norm to this (none: no clipping)."""
    double_dqn: bool = True
    """Double DQN: the online net picks the next action, the target net values it."""
    target_network: bool = True
    """Use a separate target network (false: targets from the online net, as both tutorials do)."""
    target_update_interval: int = 1
    """Gradient steps between target-network updates (SB3 counts env steps instead)."""
    tau: float = 0.02
    """Target update: Polyak weight of the online net (1.0 = hard copy)."""
    # replay and updates
    buffer_size: int = 50_000
    """Replay memory capacity (transitions)."""
    batch_size: int = 256
    """Minibatch size of a gradient step (smaller while the memory holds fewer rows)."""
    learning_starts: int = 1000
    """Env steps collected before the first gradient step."""
    num_envs: int = 8
    """Vector envs stepped together; one learn() call collects one transition from each."""
    train_freq: int = 1
    """learn() calls (batched env steps) between training rounds."""
    gradient_steps: int = 2
    """Gradient steps per training round."""
    # exploration
    epsilon_schedule: str = "linear"
    """linear (over epsilon_decay_steps), exponential (time constant epsilon_decay_steps, per env
    step) or multiplicative (x epsilon_decay_rate per gradient step)."""
    epsilon_start: float = 1.0
    """Initial probability of a random action."""
    epsilon_end: float = 0.01
    """Final (minimum) probability of a random action."""
    epsilon_decay_steps: int = 6000
    """Env steps of the linear decay, or the time constant of the exponential one."""
    epsilon_decay_rate: float = 0.999
    """Factor applied per gradient step by the multiplicative schedule."""
    # reward shaping (off by default; the tutorials used them)
    termination_reward: float | None = None
    """Replace the reward of a terminating transition by this value (Keras tutorial: -10)."""
    short_episode_reward: float | None = None
    """Replace the reward of the last transition of an episode shorter than short_episode_length."""
    short_episode_length: int = 0
    """Length below which an ending episode gets short_episode_reward (PyTorch tutorial: 195)."""
    # runtime
    simulator: str = "fast"
    """Training simulator: fast (our batched CartPole; other envs use Gymnasium) or gymnasium."""
    torch_threads: int = 1
    """CPU threads for torch (0: leave torch's default); 1 is fastest for small nets on CPU."""

    def validate(self) -> None:
        """Reject bad values with one clear line each."""
        require(len(self.hidden_sizes) >= 1, "hidden_sizes needs at least one layer, e.g. 128,128")
        require(all(h >= 1 for h in self.hidden_sizes), "hidden_sizes must all be >= 1")
        require(self.activation in ACTIVATIONS, f"activation must be one of {', '.join(ACTIVATIONS)}")
        require(0.0 <= self.dropout < 1.0, "dropout must be in [0, 1)")
        require(self.lr > 0, f"lr must be > 0, got {self.lr}")
        require(0.0 <= self.gamma <= 1.0, f"gamma must be in [0, 1], got {self.gamma}")
        require(self.loss in LOSSES, f"loss must be one of {', '.join(LOSSES)}, got {self.loss!r}")
        require(self.max_grad_norm is None or self.max_grad_norm > 0, "max_grad_norm must be > 0 or none")
        require(self.target_update_interval >= 1, "target_update_interval must be >= 1")
        require(0.0 < self.tau <= 1.0, f"tau must be in (0, 1], got {self.tau}")
        require(self.buffer_size >= 1, f"buffer_size must be >= 1, got {self.buffer_size}")
        require(self.batch_size >= 1, f"batch_size must be >= 1, got {self.batch_size}")
        require(self.learning_starts >= 0, "learning_starts must be >= 0")
        require(self.num_envs >= 1, f"num_envs must be >= 1, got {self.num_envs}")
        require(self.train_freq >= 1, f"train_freq must be >= 1, got {self.train_freq}")
        require(self.gradient_steps >= 0, f"gradient_steps must be >= 0, got {self.gradient_steps}")
        require(self.epsilon_schedule in SCHEDULES, f"epsilon_schedule must be one of {', '.join(SCHEDULES)}")
        require(
            0.0 <= self.epsilon_end <= self.epsilon_start <= 1.0,
            "need 0 <= epsilon_end <= epsilon_start <= 1",
        )
        require(self.epsilon_decay_steps >= 1, "epsilon_decay_steps must be >= 1")
        require(0.0 < self.epsilon_decay_rate <= 1.0, "epsilon_decay_rate must be in (0, 1]")
        require(self.short_episode_length >= 0, "short_episode_length must be >= 0")
        check_simulator(self.simulator)
        require(self.torch_threads >= 0, "torch_threads must be >= 0")
        problem = dqn_memory_problem(self.buffer_size, self.hidden_sizes, self.batch_size)
        require(problem is None, problem or "")


# ----------------------------------------------------------------------------------------------
# 2. The Q-network
# ----------------------------------------------------------------------------------------------


class Dropout(nn.Dropout):
    """``nn.Dropout`` with its mask drawn from ``torch.rand_like``: the same distribution (zero with
    probability p, else scaled by 1/(1-p)) from another random stream.

    On CPU torch's ``bernoulli_`` costs ~15 ns per element against ~4 for ``rand_like``: with the Keras
    tutorial's 512/256/64 net that was a third of each gradient step.
    """

    def forward(self, input: torch.Tensor) -> torch.Tensor:
        if not self.training or self.p == 0.0:
            return input
        scaled_mask = torch.rand_like(input).ge_(self.p).mul_(1.0 / (1.0 - self.p))  # 0 or 1/(1-p)
        return input * scaled_mask


class QNetwork(nn.Module):
    """MLP from observations to one Q-value per action.

    ``forward`` is the torch computation (training, and big or non-CPU batches); ``q_values`` is the
    greedy-time entry point for numpy observations, which on CPU evaluates the *same* parameters with
    numpy when the batch is small (acting in a few envs, evaluation, the web app's one observation per
    request): there torch's ~4 us per op is most of the cost, and numpy's is ~1 us.
    """

    def __init__(self, obs_dim: int, n_actions: int, config: DQNConfig):
        super().__init__()
        layers: list[nn.Module] = []
        width = obs_dim
        for hidden in config.hidden_sizes:
            layers += [nn.Linear(width, hidden), ACTIVATIONS[config.activation]()]
            if config.dropout > 0:
                layers.append(Dropout(config.dropout))
            width = hidden
        self.body = nn.Sequential(*layers)
        self.head = nn.Linear(width, n_actions)
        self.value = nn.Linear(width, 1) if config.dueling else None
        self._linears = [m for m in self.modules() if isinstance(m, nn.Linear)]
        self._widest_layer = max(m.weight.numel() for m in self._linears)
        self._numpy_cache: tuple[tuple[int, ...], list[Any] | None] | None = None

    def forward(self, observations: torch.Tensor) -> torch.Tensor:
        # module.forward(x), not module(x): nn.Module.__call__'s hook handling costs more than a
        # 64x64 layer's matmul here (no hooks are used on the layers).
        features = observations
        for module in self.body:
            features = module.forward(features)
        q = self.head.forward(features)
        if self.value is not None:  # dueling: the head gives advantages
            q = self.value.forward(features) + q - q.mean(dim=1, keepdim=True)
        return q

    def q_values(self, observations: np.ndarray, plan: list[Any] | None = None) -> np.ndarray:
        """Q-values [N, n_actions] of numpy observations, without autograd (eval mode: no dropout).

        ``plan`` is a numpy plan the caller knows to be current (a frozen policy keeps one); by
        default it is looked up, which checks that the parameters were not replaced.
        """
        observations = np.asarray(observations, dtype=np.float32)
        if plan is None and not self.training:
            plan = self._numpy_plan()
        if plan is None or len(observations) * self._widest_layer > NUMPY_MAX_WORK:
            device = self.head.weight.device
            with torch.inference_mode():
                return self.forward(torch.as_tensor(observations, device=device)).cpu().numpy()
        features = observations
        for step in plan:
            if isinstance(step, tuple):  # a linear layer: x W^T + b
                features = features @ step[0]
                features += step[1]
            else:
                features = step(features)
        return features

    def _numpy_plan(self) -> list[Any] | None:
        """The layers as numpy steps over views of the parameters (no copies), or None when numpy
        cannot run this net (not on CPU, not float32, or an activation numpy lacks)."""
        tensors = [t for layer in self._linears for t in (layer.weight, layer.bias)]
        # A parameter's memory only changes by replacement (.to(), deepcopy, assign=True loads), which
        # changes its address; in-place updates (optimizer, target lerp, load_state_dict) keep the
        # views current. The views keep the memory alive, so an address is never reused meanwhile.
        key = tuple(t.data_ptr() for t in tensors)
        if self._numpy_cache is None or self._numpy_cache[0] != key:
            usable = all(t.device.type == "cpu" and t.dtype == torch.float32 for t in tensors)
            self._numpy_cache = (key, self._build_numpy_plan() if usable else None)
        return self._numpy_cache[1]

    def _build_numpy_plan(self) -> list[Any] | None:
        def affine(layer: nn.Linear) -> tuple[np.ndarray, np.ndarray]:
            return layer.weight.detach().numpy().T, layer.bias.detach().numpy()

        plan: list[Any] = []
        for module in self.body:
            if isinstance(module, nn.Linear):
                plan.append(affine(module))
            elif isinstance(module, nn.Dropout):
                continue  # identity in eval mode
            elif type(module) in NUMPY_ACTIVATIONS:
                plan.append(NUMPY_ACTIVATIONS[type(module)])
            else:
                return None
        head = affine(self.head)
        if self.value is None:
            return [*plan, head]
        value = affine(self.value)

        def dueling(features: np.ndarray) -> np.ndarray:
            advantages = features @ head[0] + head[1]
            return (features @ value[0] + value[1]) + advantages - advantages.mean(axis=1, keepdims=True)

        return [*plan, dueling]


def _relu(x: np.ndarray) -> np.ndarray:
    return np.maximum(x, 0.0, out=x)


def _tanh(x: np.ndarray) -> np.ndarray:
    return np.tanh(x, out=x)


def _elu(x: np.ndarray) -> np.ndarray:
    return np.where(x > 0.0, x, np.expm1(np.minimum(x, 0.0)))


NUMPY_ACTIVATIONS: dict[type[nn.Module], Any] = {nn.ReLU: _relu, nn.Tanh: _tanh, nn.ELU: _elu}
"""Activations with a numpy twin for ``QNetwork.q_values`` (GELU needs erf: it stays on torch)."""
NUMPY_MAX_WORK = 100 * 64 * 64
"""Largest rows x (widest layer's weights) ``q_values`` computes with numpy: beyond ~100 rows of a
64x64 layer OpenBLAS starts a second thread (more CPU, not less), and torch is as fast there."""


# ----------------------------------------------------------------------------------------------
# 3. The Bellman target
# ----------------------------------------------------------------------------------------------


def td_targets(
    rewards: torch.Tensor,
    terminated: torch.Tensor,
    next_q_target: torch.Tensor,
    next_q_online: torch.Tensor | None,
    gamma: float,
) -> torch.Tensor:
    """``r + gamma * (1 - terminated) * Q_target(s', a*)``.

    ``a*`` is argmax of the online net's values (double DQN) when ``next_q_online`` is given, else of
    the target net's own. Only *termination* stops the bootstrap: a transition cut by the time limit
    (truncated, e.g. step 500 of CartPole-v1) was stored with ``terminated=0``, because the pole was
    still up and the state still had value. Treating truncation as termination teaches the agent that
    step 500 is a cliff, which is the classic reason a DQN "solves" CartPole and then collapses.
    """
    chooser = next_q_target if next_q_online is None else next_q_online
    next_actions = chooser.argmax(dim=1, keepdim=True)
    next_values = next_q_target.gather(1, next_actions).squeeze(1)
    return rewards + gamma * (1.0 - terminated) * next_values


# ----------------------------------------------------------------------------------------------
# 4. The learner
# ----------------------------------------------------------------------------------------------


def epsilon_at(config: DQNConfig, env_steps: int, multiplied: float) -> float:
    """Exploration rate after ``env_steps`` (``multiplied`` is the multiplicative schedule's value)."""
    start, end = config.epsilon_start, config.epsilon_end
    if config.epsilon_schedule == "linear":
        return end + (start - end) * max(0.0, 1.0 - env_steps / config.epsilon_decay_steps)
    if config.epsilon_schedule == "exponential":
        return end + (start - end) * math.exp(-env_steps / config.epsilon_decay_steps)
    return multiplied


class DQNLearner:
    """DQN as a Learner of the shared loop: one ``learn()`` = one batched env step + due updates."""

    def __init__(self, config: DQNConfig, env: EnvInfo, seed: int, device: str = "cpu"):
        config.validate()
        self.config, self.env_info, self.seed = config, env, seed
        self.device = torch.device(device)
        if config.torch_threads:
            torch.set_num_threads(config.torch_threads)
        self.rng = seed_everything(seed)  # global seeding: agents owning their generators is on its way
        self.q_net = QNetwork(env.obs_dim, env.n_actions, config).to(self.device).eval()
        self.target_net = copy.deepcopy(self.q_net) if config.target_network else None
        self.parameters = list(self.q_net.parameters())
        self.target_parameters = list(self.target_net.parameters()) if self.target_net is not None else []
        # torch's fused Adam kernel, the fastest on CPU and GPU for small nets, without torch.optim's
        # per-step wrapper and its one-off ~1.8 s import of torch._dynamo (see agents/adam.py).
        self.optimizer = FusedAdam(self.parameters, lr=config.lr)
        self.buffer = ReplayBuffer(config.buffer_size, env.obs_dim, self.device)
        self.replay_generator = torch.Generator(self.device)
        """Draws the replay minibatches (on the learner's device); seeded apart from the other streams."""
        self.replay_generator.manual_seed(_derived_seed(seed, "replay"))
        self.envs = make_vec_env(env.env_id, config.num_envs, simulator=config.simulator)
        self.observations, _ = self.envs.reset(seed=seed)
        n = config.num_envs
        self.autoreset = np.zeros(n, dtype=bool)
        """Envs whose last step ended an episode: their next step is a reset, not a transition."""
        self.episode_returns = np.zeros(n, dtype=np.float64)
        self.episode_lengths = np.zeros(n, dtype=np.int64)
        self.env_steps = 0
        self.calls = 0
        self.gradient_steps = 0
        self.epsilon_multiplied = config.epsilon_start
        self.last_loss = float("nan")
        self.last_q_mean = float("nan")
        self.use_dropout = config.dropout > 0

    # -- acting ----------------------------------------------------------------------------

    @property
    def epsilon(self) -> float:
        return epsilon_at(self.config, self.env_steps, self.epsilon_multiplied)

    def select_actions(self, observations: np.ndarray, epsilon: float) -> np.ndarray:
        """Epsilon-greedy actions for all envs with a single forward pass (skipped if all explore)."""
        n = len(observations)
        explore = self.rng.random(n) < epsilon
        actions = self.rng.integers(0, self.env_info.n_actions, size=n)
        if not explore.all():
            actions = np.where(explore, actions, self.q_net.q_values(observations).argmax(axis=1))
        return actions

    # -- one learn() call --------------------------------------------------------------------

    def learn(self) -> LearnResult:
        config = self.config
        epsilon = self.epsilon
        observations = self.observations
        actions = self.select_actions(observations, epsilon)
        next_observations, rewards, terminated, truncated, _ = self.envs.step(actions)

        # Gymnasium's next-step autoreset: an env that ended an episode at the last call has just
        # been reset (its action was ignored). That row is not a transition; drop it.
        valid = ~self.autoreset
        self.episode_returns += np.where(valid, rewards, 0.0)
        self.episode_lengths += valid
        done = (terminated | truncated) & valid
        stored_rewards = self.shape_rewards(rewards, terminated & valid, done)
        # Only `terminated` is stored as the no-bootstrap flag. At truncation (the time limit) the
        # step returns the real final observation (the reset comes on the next call), so the target
        # bootstraps from that state's value: the pole was still up.
        self.buffer.add(
            observations[valid],
            actions[valid],
            stored_rewards[valid],
            next_observations[valid],
            terminated[valid].astype(np.float32),
        )
        collected = int(valid.sum())
        self.env_steps += collected
        result = LearnResult(env_steps=collected)
        for i in np.flatnonzero(done):  # raw env returns, before any reward shaping
            result.episode_returns.append(float(self.episode_returns[i]))
            result.episode_lengths.append(int(self.episode_lengths[i]))
            self.episode_returns[i] = 0.0
            self.episode_lengths[i] = 0
        self.autoreset = done
        self.observations = next_observations

        self.calls += 1
        if self.calls % config.train_freq == 0 and self.env_steps >= config.learning_starts:
            loss = q = None
            for _ in range(config.gradient_steps):
                loss, q = self.gradient_step()
            if loss is not None and q is not None:  # one device sync per training round, not per step
                self.last_loss, self.last_q_mean = float(loss), float(q.mean())
        result.scalars = {"train/epsilon": epsilon, "train/gradient_steps": float(self.gradient_steps)}
        if self.gradient_steps:  # no loss before the first update (and metrics hold no NaN)
            result.scalars |= {"train/loss": self.last_loss, "train/q_mean": self.last_q_mean}
        return result

    def shape_rewards(self, rewards: np.ndarray, terminated: np.ndarray, done: np.ndarray) -> np.ndarray:
        """The tutorials' reward shaping, where configured; the raw rewards otherwise."""
        config = self.config
        if config.termination_reward is None and config.short_episode_reward is None:
            return rewards
        shaped = rewards.astype(np.float32, copy=True)
        if config.termination_reward is not None:
            shaped[terminated] = config.termination_reward
        if config.short_episode_reward is not None:
            short = done & (self.episode_lengths < config.short_episode_length)
            shaped[short] = config.short_episode_reward
        return shaped

    # -- one gradient step -----------------------------------------------------------------------

    def gradient_step(self) -> tuple[torch.Tensor, torch.Tensor]:
        """One update of the online net; returns its loss and Q-values (tensors: no sync here)."""
        config = self.config
        batch = self.buffer.sample(min(config.batch_size, len(self.buffer)), self.replay_generator)
        if self.use_dropout:
            self.q_net.train()
        # forward(), not __call__: no hooks are used, and the call's wrapper is ~2% of a gradient step.
        q_all = self.q_net.forward(batch.observations)
        if self.use_dropout:
            self.q_net.eval()
        with torch.no_grad():
            # Without a target network the online net (without dropout) values s', as the tutorials do.
            target_net = self.target_net if self.target_net is not None else self.q_net
            next_q_target = target_net.forward(batch.next_observations)
            next_q_online = None
            if config.double_dqn:
                same = self.target_net is None
                next_q_online = next_q_target if same else self.q_net.forward(batch.next_observations)
            targets = td_targets(batch.rewards, batch.terminated, next_q_target, next_q_online, config.gamma)
        q = q_all.gather(1, batch.actions.unsqueeze(1)).squeeze(1)
        loss = F.smooth_l1_loss(q, targets) if config.loss == "huber" else F.mse_loss(q, targets)
        self.optimizer.zero_grad()
        loss.backward()
        if config.max_grad_norm is not None:
            nn.utils.clip_grad_norm_(self.parameters, config.max_grad_norm)
        self.optimizer.step()
        self.gradient_steps += 1
        if self.target_net is not None and self.gradient_steps % config.target_update_interval == 0:
            self.update_target()
        if config.epsilon_schedule == "multiplicative" and self.epsilon_multiplied > config.epsilon_end:
            self.epsilon_multiplied = max(
                config.epsilon_end, self.epsilon_multiplied * config.epsilon_decay_rate
            )
        return loss.detach(), q.detach()

    @torch.no_grad()
    def update_target(self) -> None:
        online, target = self.parameters, self.target_parameters
        if self.config.tau >= 1.0:
            torch._foreach_copy_(target, online)
        else:
            torch._foreach_lerp_(target, online, self.config.tau)

    # -- policy and checkpoints ---------------------------------------------------------------

    def policy(self) -> QNetworkPolicy:
        """A frozen copy of the current greedy policy."""
        return QNetworkPolicy(copy.deepcopy(self.q_net), self.device)

    def state_dict(self, resume: bool) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
        tensors = {f"q_net.{k}": v for k, v in self.q_net.state_dict().items()}
        data: dict[str, Any] = {"obs_dim": self.env_info.obs_dim, "n_actions": self.env_info.n_actions}
        if not resume:
            return tensors, data
        if self.target_net is not None:
            tensors |= {f"target_net.{k}": v for k, v in self.target_net.state_dict().items()}
        optim_tensors, optim_data = self.optimizer.state_dict()
        tensors |= {f"optim.{k}": v for k, v in optim_tensors.items()}
        replay_tensors, replay_data = self.buffer.state_dict()
        tensors |= {f"replay.{k}": v for k, v in replay_tensors.items()}
        tensors["rng.torch"] = torch.get_rng_state()
        tensors["rng.replay"] = self.replay_generator.get_state()
        tensors["envs.observations"] = torch.from_numpy(np.asarray(self.observations, dtype=np.float32))
        data |= {
            "optim": optim_data,
            "replay": replay_data,
            "rng_numpy": self.rng.bit_generator.state,
            "env_steps": self.env_steps,
            "calls": self.calls,
            "gradient_steps": self.gradient_steps,
            "epsilon_multiplied": self.epsilon_multiplied,
            "autoreset": self.autoreset.tolist(),
            "episode_returns": self.episode_returns.tolist(),
            "episode_lengths": self.episode_lengths.tolist(),
            "env_state": _vector_env_state(self.envs),
        }
        return tensors, data

    def load_state_dict(self, tensors: dict[str, torch.Tensor], data: dict[str, Any]) -> None:
        self.q_net.load_state_dict(_with_prefix(tensors, "q_net."))
        if "env_steps" not in data:  # a policy-only checkpoint: weights only
            if self.target_net is not None:
                self.target_net.load_state_dict(self.q_net.state_dict())
            return
        if self.target_net is not None:
            self.target_net.load_state_dict(_with_prefix(tensors, "target_net."))
        self.optimizer.load_state_dict(_with_prefix(tensors, "optim."))
        self.buffer.load_state_dict(_with_prefix(tensors, "replay."), data["replay"])
        torch.set_rng_state(tensors["rng.torch"])
        if "rng.replay" in tensors:  # absent from checkpoints older than the torch-sampled replay
            self.replay_generator.set_state(tensors["rng.replay"])
        self.rng.bit_generator.state = data["rng_numpy"]
        self.env_steps, self.calls = int(data["env_steps"]), int(data["calls"])
        self.gradient_steps = int(data["gradient_steps"])
        self.epsilon_multiplied = float(data["epsilon_multiplied"])
        self.autoreset = np.asarray(data["autoreset"], dtype=bool)
        self.episode_returns = np.asarray(data["episode_returns"], dtype=np.float64)
        self.episode_lengths = np.asarray(data["episode_lengths"], dtype=np.int64)
        if _restore_vector_env_state(self.envs, data.get("env_state")):
            self.observations = tensors["envs.observations"].numpy().copy()
        else:
            # The env's internal state could not be saved: start fresh episodes from a seed derived
            # from the run's seed and progress (deterministic), dropping the episodes in progress.
            seed = int(np.random.SeedSequence([self.seed, self.env_steps]).generate_state(1)[0])
            self.observations, _ = self.envs.reset(seed=seed)
            self.autoreset[:] = False
            self.episode_returns[:] = 0.0
            self.episode_lengths[:] = 0


def _derived_seed(seed: int, stream: str) -> int:
    """A seed for one named random stream of a run, independent of the run seed's other uses."""
    words = np.random.SeedSequence([seed, *stream.encode()]).generate_state(2, dtype=np.uint32)
    return int(words[0]) << 32 | int(words[1])


def _with_prefix(tensors: dict[str, torch.Tensor], prefix: str) -> dict[str, torch.Tensor]:
    return {k.removeprefix(prefix): v for k, v in tensors.items() if k.startswith(prefix)}


# The per-env state of the batched CartPole vector envs: Gymnasium's CartPoleVectorEnv (public names)
# and our fast simulator (private names). Other vector envs restart their episodes on resume.
_GYMNASIUM_CARTPOLE_FIELDS = ("state", "steps", "prev_done")
"""The public state of Gymnasium's CartPoleVectorEnv (our fast simulator has ``snapshot()``)."""


def _vector_env_state(envs: Any) -> dict[str, Any] | None:
    """Plain-data snapshot of a batched CartPole vector env, or None if we do not know its state."""
    base = envs.unwrapped
    if hasattr(base, "snapshot"):  # our fast simulator
        return {"snapshot": base.snapshot()}
    fields = {name: getattr(base, name, None) for name in _GYMNASIUM_CARTPOLE_FIELDS}
    if not all(isinstance(v, np.ndarray) for v in fields.values()):
        return None
    arrays = {k: {"values": v.tolist(), "dtype": str(v.dtype)} for k, v in fields.items()}
    return {"fields": arrays, "np_random": base.np_random.bit_generator.state}


def _restore_vector_env_state(envs: Any, saved: dict[str, Any] | None) -> bool:
    """Put a vector env back where :func:`_vector_env_state` found it; False if it cannot."""
    if not saved:
        return False
    base = envs.unwrapped
    if "snapshot" in saved:
        base.restore(saved["snapshot"])
        return True
    for name, value in saved["fields"].items():
        setattr(base, name, np.asarray(value["values"], dtype=value["dtype"]))
    base.np_random.bit_generator.state = saved["np_random"]
    return True


# ----------------------------------------------------------------------------------------------
# 5. The greedy policy
# ----------------------------------------------------------------------------------------------


class QNetworkPolicy:
    """Greedy policy of a Q-network: ``act`` = argmax of ``scores`` (the Q-values)."""

    def __init__(self, q_net: QNetwork, device: str | torch.device = "cpu"):
        self.q_net = q_net.eval()
        self.device = torch.device(device)
        # The net is a frozen copy: its numpy plan, built once, stays current (the web app asks
        # for one observation at a time, where checking the plan would cost as much as using it).
        self._plan = q_net._numpy_plan()

    def scores(self, observations: np.ndarray) -> np.ndarray:
        """Q-values, shape [N, n_actions]."""
        return self.q_net.q_values(observations, self._plan)

    def act(self, observations: np.ndarray) -> np.ndarray:
        return self.scores(observations).argmax(axis=1)


def policy_from_checkpoint(checkpoint: Checkpoint) -> QNetworkPolicy:
    """Rebuild the greedy policy on CPU from a checkpoint's tensors."""
    try:
        config = build_config(DQNConfig, checkpoint.meta["config"])
        data = checkpoint.meta["learner"]
        q_net = QNetwork(int(data["obs_dim"]), int(data["n_actions"]), config)
        q_net.load_state_dict(_with_prefix(checkpoint.tensors, "q_net."))
    except (KeyError, RuntimeError, TypeError) as err:
        raise CheckpointError(f"not a usable dqn checkpoint: {err!s:.120}") from err
    return QNetworkPolicy(q_net, "cpu")


def make_learner(config: DQNConfig, env: EnvInfo, seed: int, device: str) -> DQNLearner:
    return DQNLearner(config, env, seed, device)


AGENT = AgentSpec(
    name="dqn",
    summary="Deep Q-Network (PyTorch): double DQN, replay, target network, vectorized collection",
    config_cls=DQNConfig,
    make_learner=make_learner,
    policy_from_checkpoint=policy_from_checkpoint,
    iteration="step",
    score_label="Q-values",
)

__all__ = ["AGENT", "DQNConfig", "DQNLearner", "QNetwork", "QNetworkPolicy", "td_targets"]
