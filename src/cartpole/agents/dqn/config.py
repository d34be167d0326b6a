"""DQN's settings: :class:`DQNConfig`, every setting with a one-line docstring each (presets in
``presets/dqn.toml``), checked on its own (``validate``) and against the env's observations
(``check_env``). The learning rule that reads them is :mod:`cartpole.agents.dqn.dqn`.

The learning rate's schedules are the policy-gradient agents' (constant or linear). The three
exploration schedules are the ones the tutorials used: linear (ours), exponential per env
step (the PyTorch tutorial), and multiplicative per gradient step (the Keras tutorial).
"""

from __future__ import annotations

from dataclasses import dataclass

from cartpole.agents.dqn.q_network import ACTIVATIONS, network_input_shape
from cartpole.agents.nn.conv import conv_output_size
from cartpole.agents.nn.schedules import SCHEDULES
from cartpole.core.config import require
from cartpole.core.errors import ConfigError
from cartpole.envs import EnvInfo, check_simulator

EPSILON_SCHEDULES = ("linear", "exponential", "multiplicative")
LOSSES = ("huber", "mse")
OPTIMIZERS = ("adam", "rmsprop")


@dataclass
class DQNConfig:
    """Hyperparameters of DQN. Defaults are the ``default`` preset's values for CartPole-v1 but three
    that the preset changed later and the other presets, and preset files, that do not name them keep:
    ``n_step`` (1 here: one-step DQN; 3 in the preset), ``gamma`` (0.99; 0.985) and ``epsilon_end``
    (0.01; 0.05)."""

    # network
    hidden_sizes: tuple[int, ...] = (64, 64)
    """Widths of the hidden layers of the Q-network MLP (none: a linear head on the inputs or the
    convolutional features)."""
    activation: str = "relu"
    """Hidden-layer activation: relu, tanh, elu or gelu."""
    dropout: float = 0.0
    """Dropout after each hidden layer while training (0 = none); acting and targets run without it."""
    dueling: bool = False
    """Dueling head: Q = V + A - mean(A)."""
    conv_layers: tuple[tuple[int, int, int], ...] = ((16, 8, 4), (32, 3, 1))
    """Image observations only: the convolutional layers before the MLP, each [filters, kernel size,
    stride] (no padding, ReLU after each); the default is the actor-critic agents' trunk."""
    frame_difference: bool = False
    """Image observations only: show the network the last frame minus the one before it (one
    channel), the old PyTorch tutorial's screen difference, instead of the whole frame stack."""
    # learning
    optimizer: str = "adam"
    """adam, or rmsprop (torch.optim.RMSprop's defaults: alpha 0.99, eps 1e-8, no momentum)."""
    lr: float = 2e-3
    """Learning rate of the optimizer (its start, with a linear lr_schedule)."""
    lr_schedule: str = "constant"
    """constant, or linear: each seed's learning rate decays to 0 at schedule_steps of its env steps."""
    schedule_steps: int = 100_000
    """Env steps over which a linear lr_schedule decays the learning rate to 0."""
    gamma: float = 0.99
    """Discount factor."""
    loss: str = "huber"
    """TD loss: huber (smooth L1) or mse."""
    max_grad_norm: float | None = None
    """Clip the gradient's global norm to this (none: no clipping)."""
    max_grad_value: float | None = None
    """Clamp every gradient value to [-max_grad_value, max_grad_value] (none: no clamping; the old
    PyTorch tutorial clamped to 1)."""
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
    learning_starts: int = 500
    """Env steps collected before the first gradient step."""
    num_envs: int = 8
    """Vector envs stepped together; one learn() call collects one transition from each."""
    train_freq: int = 1
    """learn() calls (batched env steps) between training rounds."""
    gradient_steps: int = 4
    """Gradient steps per training round."""
    n_step: int = 1
    """Steps of reward a replay row sums before its target bootstraps (with gamma^n_step): n-step
    returns, as Rainbow's and SB3's n-step replay; 1 is one-step DQN."""
    # exploration
    epsilon_schedule: str = "linear"
    """linear (over epsilon_decay_steps), exponential (time constant epsilon_decay_steps, per env
    step) or multiplicative (x epsilon_decay_rate per gradient step)."""
    epsilon_start: float = 1.0
    """Initial probability of a random action."""
    epsilon_end: float = 0.01
    """Final (minimum) probability of a random action."""
    epsilon_decay_steps: int = 5000
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

    def validate(self) -> None:
        """Reject bad values with one clear line each."""
        require(all(h >= 1 for h in self.hidden_sizes), "hidden_sizes must all be >= 1")
        require(
            all(len(layer) == 3 and all(n >= 1 for n in layer) for layer in self.conv_layers),
            "conv_layers must be [filters, kernel size, stride] triples of whole numbers >= 1, "
            "e.g. [[16, 8, 4], [32, 3, 1]]",
        )
        require(self.optimizer in OPTIMIZERS, f"optimizer must be one of {', '.join(OPTIMIZERS)}")
        require(self.activation in ACTIVATIONS, f"activation must be one of {', '.join(ACTIVATIONS)}")
        require(0.0 <= self.dropout < 1.0, "dropout must be in [0, 1)")
        require(self.lr > 0, f"lr must be > 0, got {self.lr}")
        require(self.lr_schedule in SCHEDULES, f"lr_schedule must be one of {', '.join(SCHEDULES)}")
        require(self.schedule_steps >= 1, f"schedule_steps must be >= 1, got {self.schedule_steps}")
        require(0.0 <= self.gamma <= 1.0, f"gamma must be in [0, 1], got {self.gamma}")
        require(self.loss in LOSSES, f"loss must be one of {', '.join(LOSSES)}, got {self.loss!r}")
        require(self.max_grad_norm is None or self.max_grad_norm > 0, "max_grad_norm must be > 0 or none")
        require(self.max_grad_value is None or self.max_grad_value > 0, "max_grad_value must be > 0 or none")
        require(self.target_update_interval >= 1, "target_update_interval must be >= 1")
        require(0.0 < self.tau <= 1.0, f"tau must be in (0, 1], got {self.tau}")
        require(self.buffer_size >= 1, f"buffer_size must be >= 1, got {self.buffer_size}")
        require(self.batch_size >= 1, f"batch_size must be >= 1, got {self.batch_size}")
        require(self.learning_starts >= 0, "learning_starts must be >= 0")
        require(self.num_envs >= 1, f"num_envs must be >= 1, got {self.num_envs}")
        require(self.train_freq >= 1, f"train_freq must be >= 1, got {self.train_freq}")
        require(self.gradient_steps >= 0, f"gradient_steps must be >= 0, got {self.gradient_steps}")
        require(1 <= self.n_step <= 100, f"n_step must be between 1 and 100, got {self.n_step}")
        require(
            self.epsilon_schedule in EPSILON_SCHEDULES,
            f"epsilon_schedule must be one of {', '.join(EPSILON_SCHEDULES)}",
        )
        require(
            0.0 <= self.epsilon_end <= self.epsilon_start <= 1.0,
            "need 0 <= epsilon_end <= epsilon_start <= 1",
        )
        require(self.epsilon_decay_steps >= 1, "epsilon_decay_steps must be >= 1")
        require(0.0 < self.epsilon_decay_rate <= 1.0, "epsilon_decay_rate must be in (0, 1]")
        require(self.short_episode_length >= 0, "short_episode_length must be >= 0")
        check_simulator(self.simulator)

    def check_env(self, env: EnvInfo) -> None:
        """Reject settings that do not fit ``env``'s observations, one line each (before a run starts)."""
        if not env.is_image:
            require(
                not self.frame_difference,
                f"frame_difference needs image observations (e.g. cartpole/CartPolePixels-v1); "
                f"{env.env_id}'s are not images",
            )
            return
        require(
            not self.frame_difference or env.obs_shape[0] >= 2,
            f"frame_difference needs at least 2 frames a stack; {env.env_id} has {env.obs_shape[0]}",
        )
        try:
            conv_output_size(network_input_shape(env.obs_shape, self.frame_difference), self.conv_layers)
        except ValueError:
            raise ConfigError(
                f"conv_layers {[list(layer) for layer in self.conv_layers]} shrink {env.env_id}'s images "
                f"{list(env.obs_shape)} to nothing: use smaller kernels or strides, or fewer layers"
            ) from None


__all__ = ["EPSILON_SCHEDULES", "LOSSES", "OPTIMIZERS", "DQNConfig"]
