"""The agents we ship, by name: how to configure, build and reload each one."""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from cartpole.envs import EnvInfo, UnsupportedEnvError, env_info, resolve_simulator
from cartpole.evaluation import BlockActor, Policy
from cartpole.runs import Checkpoint, CheckpointError, RunDir, load_checkpoint

if TYPE_CHECKING:
    from torch import nn

    from cartpole.agents.population import Population


@dataclass(frozen=True)
class AgentSpec:
    """Everything the rest of the package knows of one agent; found by name with :func:`get_agent`.
    Its presets are ``presets/<name>.toml`` and its sweep space ``search_spaces/<name>.toml``."""

    name: str
    summary: str
    config_cls: type
    """Its settings (a dataclass with ``validate()``), built from presets and ``--set``."""
    make_population: Callable[[Any, EnvInfo, list[int], str], Population]
    """(config, env info, seeds, device) -> every seed batched in one learner, on any env (a single
    run, ``--seed N``, is a population of one)."""
    policy_from_checkpoint: Callable[[Checkpoint], Policy]
    """Rebuild the greedy policy from a checkpoint's tensors and metadata."""
    bytes_per_seed: Callable[[Any, EnvInfo], int]
    """(config, env info) -> about how much memory one seed takes, checked before training starts."""
    iteration: str = "step"
    """What one ``learn()`` call is, in words: "generation" or "step"."""
    score_label: str = "score"
    """What its policy's ``scores()`` are, for people ("Q-values", "action probabilities", ...)."""
    stacked_actor: Callable[[list[Policy], int], BlockActor | None] | None = None
    """(policies from its checkpoints, observation size) -> one actor for all of them in one pass,
    each acting as it does alone, or None where they do not stack: how a population's verdicts
    are played (else each policy acts in turn)."""
    image_observations: bool = False
    """Whether it can learn from image observations ``[channels, height, width]`` (it has a
    convolutional network), e.g. ``cartpole/CartPolePixels-v1``."""
    scores_network: Callable[[Checkpoint], nn.Module] | None = None
    """A checkpoint's greedy path as one torch module, for export (:mod:`cartpole.export`):
    observations ``[N, *obs_shape]`` (as the env gives them) -> the scores ``[N, n_actions]`` its
    policy acts on, the action being their argmax (Q-values, action logits, linear scores), with
    the observations' standardization or scaling inside. Computed exactly where acting takes fast
    approximations (:mod:`cartpole.agents.nn.fast_tanh`); None: the agent cannot be exported."""

    def check_env(self, env: EnvInfo) -> None:
        """UnsupportedEnvError (one line) when this agent cannot learn on ``env``'s observations:
        checked before anything is allocated or written."""
        if env.is_image and not self.image_observations:
            able = [spec.name for spec in agents().values() if spec.image_observations]
            raise UnsupportedEnvError(
                f"{self.name} has no convolutional network yet: train {' or '.join(able)} on {env.env_id} "
                f"(its observations are images {list(env.obs_shape)})"
            )

    def policies_actor(self, policies: list[Policy], obs_dim: int) -> BlockActor:
        """``policies`` of this agent as one :data:`~cartpole.evaluation.BlockActor` (policy b acts
        for block b): stacked where they stack, else each in turn. Each policy's actions are those
        it takes alone."""
        stacked = self.stacked_actor(policies, obs_dim) if self.stacked_actor else None
        return stacked or one_by_one_actor(policies)

    def batches(self, config: Any, env: EnvInfo) -> bool:
        """Whether seeds of ``config`` on ``env`` also step their envs together (CartPole on the fast
        simulator), so that one process training them all beats a process per seed. (Elsewhere a
        population steps each seed's Gymnasium envs in turn; ``compare`` runs such seeds in
        parallel processes instead.)"""
        return resolve_simulator(env, config.simulator) == "fast"


def one_by_one_actor(policies: list[Policy]) -> BlockActor:
    """``policies`` as one :data:`~cartpole.evaluation.BlockActor`, each acting for its block in turn."""

    def act(observations: np.ndarray, blocks: np.ndarray) -> np.ndarray:
        rows = np.split(observations, len(blocks))
        return np.concatenate([policies[b].act(mine) for b, mine in zip(blocks, rows, strict=True)])

    return act


AGENT_MODULES = {
    "random-search": "cartpole.agents.linear.search",
    "hill-climbing": "cartpole.agents.linear.search",
    "cem": "cartpole.agents.linear.search",
    "dqn": "cartpole.agents.dqn.dqn",
    "reinforce": "cartpole.agents.actor_critic.reinforce",
    "a2c": "cartpole.agents.actor_critic.a2c",
    "ppo": "cartpole.agents.actor_critic.ppo",
}
"""Agent name -> the module that defines its spec and its learner, batched over seeds (imported only
when the agent is used: torch is slow)."""


def build_population(
    spec: AgentSpec, config: Any, env: EnvInfo, seeds: list[int], device: str = "cpu"
) -> Population:
    """``seeds`` of agent ``spec`` with ``config`` on ``env``, batched in one learner. A single run is
    a population of one, bit for bit that seed in any population (``tests/test_one_engine.py``)."""
    spec.check_env(env)
    return spec.make_population(config, env, seeds, device)


DEFAULT_AGENT = "dqn"
"""What ``cartpole train`` trains when no agent is named (and the web app's training form shows first)."""


def agent_names() -> list[str]:
    return list(AGENT_MODULES)


def get_agent(name: str) -> AgentSpec:
    """The spec of agent ``name``, importing its module on first use."""
    if name not in AGENT_MODULES:
        raise ValueError(f"unknown agent {name!r}; choose one of: {', '.join(AGENT_MODULES)}")
    module = importlib.import_module(AGENT_MODULES[name])
    specs = getattr(module, "AGENTS", None) or [module.AGENT]
    return next(spec for spec in specs if spec.name == name)


def agents() -> dict[str, AgentSpec]:
    """Every agent by name (imports every agent module)."""
    return {name: get_agent(name) for name in AGENT_MODULES}


FALLBACK_ORDER = ("best", "solved", "latest")
"""A run folder's checkpoints in the order ``cartpole eval`` and ``record`` try them."""


def _candidates(path: Path) -> list[Path]:
    """The checkpoint files to try for ``path``: itself, or a run folder's in FALLBACK_ORDER."""
    if not path.is_dir():
        return [path]
    run = RunDir.open(path)
    found = [run.checkpoint_path(n) for n in FALLBACK_ORDER if run.checkpoint_path(n).is_file()]
    if not found:
        raise CheckpointError(f"run {path} has no checkpoint yet; train it (or wait for one)")
    return found


@dataclass(frozen=True)
class OpenedPolicy:
    """A saved agent, ready to act: which file it came from, and the unusable ones passed over."""

    path: Path
    checkpoint: Checkpoint
    policy: Policy
    skipped: list[str]
    """One line per checkpoint of the run that could not be used, tried before ``path``."""

    @property
    def env(self) -> EnvInfo:
        """The env the agent was trained on, as configured (its kwargs and wrappers)."""
        return checkpoint_env(self.checkpoint)


def checkpoint_env(checkpoint: Checkpoint) -> EnvInfo:
    """The env ``checkpoint``'s agent was trained on, with the kwargs and wrappers it records."""
    return env_info(checkpoint.env_id, checkpoint.env_kwargs, checkpoint.wrappers)


def load_policy(path: str | Path) -> Policy:
    """Load any saved agent of ours as a greedy Policy."""
    return open_policy(path).policy


def open_policy(path: str | Path, env_id: str | None = None) -> OpenedPolicy:
    """The greedy policy of a checkpoint file, or of a run folder: its best checkpoint, else solved,
    else latest, passing over (and listing in ``skipped``) ones that are corrupt. With ``env_id``,
    CheckpointError unless the policy fits that env's observations and actions."""
    skipped: list[str] = []
    candidates = _candidates(Path(path))
    for file in candidates:
        try:
            checkpoint = load_checkpoint(file)
            policy = policy_of(checkpoint, file)
        except CheckpointError as err:
            if file == candidates[-1]:
                raise CheckpointError("; ".join([*skipped, str(err)])) from err
            skipped.append(str(err))
            continue
        if env_id is not None:
            check_fits_env(checkpoint, file, env_id)
        return OpenedPolicy(file, checkpoint, policy, skipped)
    raise AssertionError("unreachable: _candidates is never empty")


def policy_of(checkpoint: Checkpoint, file: Path) -> Policy:
    """The greedy policy a checkpoint holds; CheckpointError if its tensors or metadata do not fit."""
    spec = spec_of(checkpoint)
    try:
        policy = spec.policy_from_checkpoint(checkpoint)
        policy.act(np.zeros((1, *fitted_observation(checkpoint)), dtype=np.float32))  # right sizes?
        return policy
    except CheckpointError as err:
        raise CheckpointError(f"{file}: {err}") from err
    except (KeyError, IndexError, TypeError, ValueError, RuntimeError, AttributeError) as err:
        raise CheckpointError(
            f"{file} is not a usable {spec.name} checkpoint ({type(err).__name__}: {err!s:.100}); "
            "use another checkpoint of the run or train again"
        ) from err


def fitted_shape(checkpoint: Checkpoint) -> tuple[int, int]:
    """(observations, actions) of the env a checkpoint's agent was built for."""
    learner = checkpoint.meta.get("learner")
    learner = learner if isinstance(learner, dict) else {}
    try:
        return int(learner["obs_dim"]), int(learner["n_actions"])
    except (KeyError, TypeError, ValueError):
        own = env_info(checkpoint.env_id)
        return own.obs_dim, own.n_actions


def fitted_observation(checkpoint: Checkpoint) -> tuple[int, ...]:
    """The observation shape of the env a checkpoint's agent was built for (flat: ``(obs_dim,)``;
    checkpoints from before image observations name no shape: flat)."""
    learner = checkpoint.meta.get("learner")
    if isinstance(learner, dict) and isinstance(learner.get("obs_shape"), list):
        return tuple(int(n) for n in learner["obs_shape"])
    return (fitted_shape(checkpoint)[0],)


def check_fits_env(checkpoint: Checkpoint, file: Path, env_id: str) -> None:
    """CheckpointError unless the checkpoint's agent sees as many observations, and has as many
    actions, as ``env_id`` (a CartPole agent cannot play Acrobot)."""
    target = env_info(env_id)
    shape = fitted_shape(checkpoint)
    if shape != (target.obs_dim, target.n_actions):
        raise CheckpointError(
            f"{file} holds a {checkpoint.agent} agent for {checkpoint.env_id} ({shape[0]} observations, "
            f"{shape[1]} actions); {env_id} has {target.obs_dim} observations and {target.n_actions} "
            f"actions: evaluate it on an env like {checkpoint.env_id}"
        )


def spec_of(checkpoint: Checkpoint) -> AgentSpec:
    """The agent that wrote ``checkpoint``; CheckpointError if we do not know it."""
    agent = checkpoint.meta.get("agent")
    if agent not in AGENT_MODULES:
        raise CheckpointError(f"checkpoint names an unknown agent {agent!r}")
    return get_agent(str(agent))
