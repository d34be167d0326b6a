"""Agents: every algorithm written once, batched over a leading seed axis, a single run being a
population of one. Each algorithm is a folder (dqn/, actor_critic/, linear/: its settings, its one
learner and its spec) standing on the parts they share here (registry.py, which finds an agent by
name; population.py, what the training engine drives; learner.py, presets.py) and on nn/, the
building blocks, which know no agent. The algorithms do not import each other. What one seed of an
agent holds in memory is its spec's ``bytes_per_seed``, which the training session checks before
anything is allocated."""
