"""Agents: each algorithm with its settings and a seed's own learner (dqn.py, ppo.py, ...), its
batched population over a seed axis (dqn_population.py, actor_critic_population.py,
linear_population.py, which also hold the agents' specs), the registry that finds them by name, and
nn/, the building blocks they share."""
