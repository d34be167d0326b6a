"""The policy-gradient agents, PPO, A2C and REINFORCE: their configs (ppo.py, a2c.py, reinforce.py)
on the settings, advantages and checkpoint policy they share (policy_gradient.py) and the network
with its greedy policy (network.py), under their learners batched over seeds (population.py, with
the specs)."""
