"""Experiments: many seeds of several agents compared with honest statistics, and Optuna sweeps.

Above training (it starts runs) and plotting (it draws their curves), below the web app and the CLI.
"""
