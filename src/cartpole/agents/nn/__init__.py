"""Building blocks of the neural agents, batched over seeds where it pays: numpy snapshots of
networks for greedy play (numpy_mlp, with fast_tanh), S networks' parameters in one flat tensor
(flat_parameters), S linear layers as one (stacked_linear), S conv layers, one conv2d per seed
(stacked_conv), Adam and RMSprop per seed row (population_optimizers). They know no agent: the
algorithms in :mod:`cartpole.agents`' folders are built from them."""
