"""Agents: every algorithm written once, batched over a leading seed axis, a single run being a
population of one. Each algorithm family is a folder (dqn/, actor_critic/, linear/) with one file per
learning rule (dqn/dqn.py; actor_critic/ppo.py, a2c.py, reinforce.py; linear/search.py: its config,
what one update does, its spec) on the family's shared parts, and on the parts every family shares
here: registry.py (an agent by name), population.py (what the training engine drives), episodes.py
(the seeds' envs and episodes), seed_state.py (one seed's checkpoint), learner.py, presets.py; and
nn/, the building blocks, which know no agent. The families do not import each other. What one seed
of an agent holds in memory is its spec's ``bytes_per_seed``, which the training session checks
before anything is allocated."""
