"""A run folder as a notebook sees it: train one, open one, and show what it did inline."""

from __future__ import annotations

import html
import io
from pathlib import Path
from typing import TYPE_CHECKING, Any

from cartpole.evaluation import MIN_EPISODES_FOR_SOLVED, EvalReport, evaluate
from cartpole.notebook.animation import Animation, Mode, show
from cartpole.plotting import XAxis, runs_figure
from cartpole.runs import RunDir, RunError, RunSummary, summarize_run

if TYPE_CHECKING:
    from matplotlib.figure import Figure


class Plot:
    """A matplotlib figure that a notebook shows inline (``_repr_png_``) whatever its backend, and
    that the caller can still change (``.figure``) or save (``.save``)."""

    def __init__(self, figure: Figure, dpi: int = 100):
        self.figure, self.dpi = figure, dpi

    def _repr_png_(self) -> bytes:
        buffer = io.BytesIO()
        self.figure.savefig(buffer, format="png", dpi=self.dpi)
        return buffer.getvalue()

    def save(self, path: str | Path, dpi: int = 150) -> Path:
        self.figure.savefig(path, dpi=dpi)
        return Path(path)

    def __repr__(self) -> str:
        width, height = self.figure.get_size_inches()
        return f"<Plot {width:g}x{height:g} in, {len(self.figure.axes)} panel(s)>"


class Run:
    """One run folder (``runs/<env>__<agent>__s<seed>__<time>/``): what trained, how far, the
    verdict, and ways to look at it. Each property reads the folder again, so a run still training
    (in another process) shows where it is now."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        if not (self.path / "config.json").is_file():
            raise RunError(f"{self.path} is not a run folder (no config.json); pass a folder under runs/")

    @property
    def summary(self) -> RunSummary:
        return summarize_run(self.path)

    @property
    def agent(self) -> str | None:
        return self.summary.agent

    @property
    def env_id(self) -> str:
        return self.summary.env_id or "CartPole-v1"

    @property
    def seed(self) -> int | None:
        return self.summary.seed

    @property
    def report(self) -> EvalReport | None:
        """The final verdict (``eval.json``): the kept best policy on 100 fresh episodes."""
        data = RunDir.open(self.path).eval_report()
        return EvalReport.from_dict(data) if data else None

    @property
    def solved(self) -> bool:
        return self.summary.solved

    @property
    def verdict(self) -> str | None:
        return self.summary.verdict

    def plot(self, x_axis: XAxis = "steps", window: int | None = None) -> Plot:
        """The learning curve: episode returns (smoothed) and evaluations, inline."""
        return Plot(runs_figure([self.path], x_axis=x_axis, window=window))

    def show(self, episodes: int = 3, *, seed: int = 0, mode: Mode = "auto") -> Animation:
        """Greedy episodes of the run's kept best policy (else its latest), animated inline."""
        return show(self.path, self.env_id, episodes=episodes, seed=seed, mode=mode)

    def evaluate(self, episodes: int = MIN_EPISODES_FOR_SOLVED, seed: int | None = None) -> EvalReport:
        """The run's kept best policy on ``episodes`` greedy episodes of Gymnasium's own env as the run
        trained on it (its kwargs and wrappers; the env's own reward and episodes), from fresh seeds
        unless ``seed`` is given: Gymnasium's rule, as ``cartpole eval`` judges."""
        from cartpole.agents.registry import open_policy

        opened = open_policy(self.path)
        return evaluate(opened.policy, opened.env, episodes, seed)

    def __repr__(self) -> str:
        s = self.summary
        verdict = s.verdict or "no verdict yet"
        return f"<Run {s.name}: {s.agent} on {s.env_id}, seed {s.seed}, {s.state}; {verdict}>"

    def _repr_html_(self) -> str:
        s = self.summary
        rows: list[tuple[str, Any]] = [
            ("agent", f"{s.agent} ({s.preset or 'default'} preset)"),
            ("env", s.env_id),
            ("seed", s.seed),
            ("state", s.state),
            ("env steps", f"{s.env_steps:,}" if s.env_steps is not None else "-"),
            ("episodes", f"{s.episodes:,}" if s.episodes is not None else "-"),
            ("folder", s.path),
        ]
        cells = "".join(
            f'<tr><th style="text-align:left">{html.escape(k)}</th><td style="text-align:left">'
            f"{html.escape(str(v))}</td></tr>"
            for k, v in rows
        )
        color = "#17804a" if s.solved else "#b03a2e"
        verdict = html.escape(s.verdict or s.problem or "no verdict yet")
        return f'<div><table>{cells}</table><b style="color:{color}">{verdict}</b></div>'


def open_run(path: str | Path) -> Run:
    """A run folder trained earlier (by ``cartpole train``, ``train`` here, or a sweep)."""
    return Run(path)


def train(
    agent: str = "dqn",
    env: str = "CartPole-v1",
    *,
    seed: int = 0,
    preset: str | None = None,
    budget: str | None = None,
    runs_dir: str | Path = "runs",
    device: str = "auto",
    progress: bool = True,
    tensorboard: bool = False,
    **settings: Any,
) -> Run:
    """Train ``agent`` on ``env`` as ``cartpole train`` does (a new run folder under ``runs_dir``,
    checkpoints, the final verdict on 100 fresh episodes of Gymnasium's env) and return the run.

    ``preset`` None takes the agent's preset for ``env`` (``cartpole presets`` lists them), as
    ``cartpole train`` without ``--preset`` does. ``settings`` override the preset's, as ``--set``
    does (``train("dqn", lr=1e-3)``); ``budget`` as ``--budget`` ("50k" env steps, "300ep", "20gen",
    "90s"). ``progress``: a progress bar in a notebook, plain lines elsewhere. ``tensorboard`` as
    ``--tensorboard``: the metrics, the settings as hyperparameters (the final verdict their metric)
    and the command in ``<run>/tensorboard/`` (needs the tensorboard extra). The run's config.json
    records the ``cartpole train`` command that starts the same run (``train("dqn", seed=2, lr=1e-3)``:
    ``cartpole train dqn --seed 2 --set lr=0.001``), not the notebook kernel's command line: TensorBoard's
    command text and a hub card's "How it was trained" show it. torch computes with
    ``cartpole train``'s default thread count while it trains (one thread on state observations),
    and with the caller's again after.
    """
    from cartpole.training import train as train_run
    from cartpole.training.threads import default_torch_threads, torch_threads

    with torch_threads(default_torch_threads(env)):
        outcome = train_run(
            agent,
            env,
            seed=seed,
            preset=preset,
            overrides=settings or None,
            budget=budget,
            runs_dir=runs_dir,
            device=device,
            quiet=not progress,
            tensorboard=tensorboard,
        )
    return Run(outcome.run.path)


__all__ = ["Plot", "Run", "open_run", "train"]
