"""DQN with its Double and Dueling options and the tutorials' presets: its settings, TD target and
exploration (algorithm.py), the Q-network and its greedy policy (q_network.py), and its learner, S
seeds' networks, optimizers and replay memories batched in one (population.py, with the spec)."""
