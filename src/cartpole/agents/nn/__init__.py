"""Building blocks of the neural agents, batched over seeds where it pays. They know no agent: the
algorithms in :mod:`cartpole.agents`' folders are built from them.

A network exists in up to six forms, each in one place, each for one reason (stated in that
module, with the benchmark table that measures it):

1. the ``nn.Module`` (``ActorCritic`` in ``actor_critic/network.py``, ``QNetwork`` in
   ``dqn/q_network.py``): what a checkpoint holds (its state dict) and what each seed is
   initialized as; the reference the other forms are tested against;
2. S networks stacked on a seed axis: their parameters in one flat tensor
   (:mod:`~cartpole.agents.nn.flat_parameters`), each layer one kernel for every seed
   (:mod:`~cartpole.agents.nn.stacked_linear`, :mod:`~cartpole.agents.nn.stacked_conv`): what a
   population trains;
3. an MLP's gradients by hand (:func:`~cartpole.agents.nn.stacked_linear.mlp_gradients`): what an
   update of a stacked MLP backpropagates with; for a tanh MLP, forward and backward each one
   compiled call of the same kernels in the same order (:mod:`~cartpole.agents.nn.fused_mlp`, the
   same bits without the Python between a small network's dozen calls);
4. a NumPy twin (:mod:`~cartpole.agents.nn.numpy_mlp`, with :mod:`~cartpole.agents.nn.fast_tanh`):
   what a rollout and DQN's batched env step act through;
5. a greedy policy's compiled forward pass (:mod:`~cartpole.agents.nn.greedy_play`): what every
   greedy MLP policy acts through, and what plays an evaluation's whole episodes on our simulator;
6. the optimizer's numba pass over the flat rows (:mod:`~cartpole.agents.nn.population_optimizers`).

Every product and every sum over a seed's rows that forms 2-4 compute runs in an order of our own
(:mod:`~cartpole.agents.nn.fixed_order`), so a seed's bits never depend on the seeds beside it, on
any CPU; the convolutions are one library call per seed on fresh copies (stacked_conv).

Besides: per-seed statistics over the valid rows of a batch (masked), the convolutional trunk's
generic pieces (conv), fixed observation standardization (standardize) and the learning rate's
schedules (schedules).
"""
