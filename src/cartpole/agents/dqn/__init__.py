"""DQN with its Double and Dueling options and the tutorials' presets: the learning rule in dqn.py
(targets, loss, gradient steps, target updates, one learn(); the spec), its settings in config.py, on
the parts it runs on: the population's networks, replay, envs, acting and checkpoints
(population.py), the stacked networks (stacked.py), the replay memories (replay.py) with their n-step
rows (n_step.py), and the Q-network with its greedy policy (q_network.py)."""
