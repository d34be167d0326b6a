"""Agents: each algorithm's settings (dqn.py, ppo.py, ...) and its one learner, batched over a seed
axis, a single run being a population of one (dqn_population.py, actor_critic_population.py,
linear_population.py, which also hold the agents' specs), the registry that finds them by name, and
nn/, the building blocks they share."""
