"""The notebook API: train, open and show agents inline in Jupyter, JupyterLab, VS Code and Colab.

    import cartpole
    run = cartpole.train("dqn", seed=0)   # a notebook progress bar, then the run, shown as a table
    run.plot()                            # the learning curve, inline
    run.show(episodes=3)                  # greedy episodes, animated, with the per-action scores
    run.evaluate()                        # 100 fresh episodes on Gymnasium's env: the verdict
    cartpole.show("runs/CartPole-v1__dqn__s0__...")   # any saved agent

Everything here is built on the library below it (training, evaluation, plotting, recording); what
it adds is how results display: ``_repr_html_`` and ``_repr_png_`` (IPython's display protocol), so
nothing is drawn or imported from IPython until a notebook asks.
"""

from __future__ import annotations

from cartpole.notebook.animation import Animation, show
from cartpole.notebook.run import Plot, Run, open_run, train

__all__ = ["Animation", "Plot", "Run", "open_run", "show", "train"]
