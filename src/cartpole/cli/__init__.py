"""The cartpole command line."""
