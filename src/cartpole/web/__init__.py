"""The local web app: watch agents, follow training live, play CartPole yourself (``cartpole serve``)."""
