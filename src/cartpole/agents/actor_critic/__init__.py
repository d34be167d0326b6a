"""The actor-critic agents, PPO, A2C and REINFORCE, each learning rule in its own file (ppo.py, a2c.py,
reinforce.py: its config, its update, its spec) on the parts they share: the base of their batched
populations (population.py), the rollout and GAE (rollout.py), the stacked networks with their
backward pass by hand (stacked.py), the network and its greedy policy (network.py), and the common
settings and checkpoint policy (policy_gradient.py)."""
