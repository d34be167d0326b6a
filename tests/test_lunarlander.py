"""LunarLander-v3 (Box2D, the box2d extra): its presets, and what a resume can keep of its envs.
(Whether the presets solve it is benchmarks/README.md#lunarlander's table, not a test.)"""

from __future__ import annotations

import pytest

pytest.importorskip("Box2D", reason="LunarLander needs the box2d extra")

from cartpole.agents.presets import env_preset
from cartpole.envs import env_info
from cartpole.envs.resumable_envs import why_episodes_restart
from cartpole.training.request import plan_training


def test_lunarlander_is_read_from_the_registry():
    info = env_info("LunarLander-v3")
    assert (info.obs_dim, info.n_actions, info.reward_threshold, info.max_episode_steps) == (8, 4, 200, 1000)


@pytest.mark.parametrize("agent", ["ppo", "dqn"])
def test_ppo_and_dqn_take_their_lunarlander_presets_there(agent: str):
    assert env_preset(agent, "LunarLander-v3") == "lunarlander"
    plan = plan_training(agent, "LunarLander-v3", 1)
    assert plan.preset == "lunarlander" and plan.settings.confirm_solves


def test_box2d_state_cannot_be_saved_so_a_resume_starts_fresh_episodes():
    assert "keeps no public state" in (why_episodes_restart(env_info("LunarLander-v3")) or "")
    assert why_episodes_restart(env_info("Acrobot-v1")) is None  # its state is public: kept
    assert why_episodes_restart(env_info("CartPole-v1")) is None
    wrapped = env_info("Acrobot-v1", wrappers=["gymnasium.wrappers:RecordEpisodeStatistics"])
    assert "wrappers" in (why_episodes_restart(wrapped) or "")
