"""cartpole as a Gymnasium plugin: its envs are registered the way third-party envs are."""

from __future__ import annotations

import subprocess
import sys

import gymnasium as gym
import numpy as np

import cartpole  # noqa: F401  (the import registers the envs)


def run_fresh(code: str) -> str:
    """Run ``code`` in a new interpreter (no cartpole import unless the code does it)."""
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return done.stdout.strip()


def test_make_with_module_prefix_needs_no_import():
    out = run_fresh(
        "import sys, gymnasium as gym\n"
        "assert 'cartpole' not in sys.modules\n"
        "env = gym.make('cartpole:cartpole/CartPole-v1')\n"
        "print(type(env.unwrapped).__module__, env.spec.max_episode_steps)"
    )
    assert out == "cartpole.envs.fast 500"


def test_import_registers_both_versions_with_gymnasium_limits():
    for version, limit in (("v1", 500), ("v0", 200)):
        spec = gym.spec(f"cartpole/CartPole-{version}")
        assert spec.max_episode_steps == limit
        assert spec.reward_threshold == gym.spec(f"CartPole-{version}").reward_threshold


def test_make_vec_after_import_steps_our_vector_env():
    envs = gym.make_vec("cartpole/CartPole-v1", num_envs=8)
    observations, _ = envs.reset(seed=0)
    assert observations.shape == (8, 4)
    _, rewards, _, truncated, _ = envs.step(np.ones(8, dtype=np.int64))
    assert rewards.tolist() == [1.0] * 8 and not truncated.any()
    envs.close()


def test_import_compiles_nothing():
    """Registration is cheap: importing cartpole does not import numba or the kernels."""
    out = run_fresh(
        "import sys, cartpole\nprint('numba' in sys.modules, 'cartpole.envs.fast' in sys.modules)"
    )
    assert out == "False False"
