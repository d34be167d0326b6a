"""Every callback of the shared loop in isolation, driven by a scripted fake learner."""

from __future__ import annotations

import io
import os
import time
from typing import Any

import numpy as np
import pytest
import torch

from cartpole.agents.linear.population import LinearPopulation
from cartpole.agents.registry import get_agent
from cartpole.core.names import StopReason
from cartpole.envs import env_info
from cartpole.evaluation import EvalReport
from cartpole.runs import LiveStatus, RunDir, load_checkpoint
from cartpole.training import Budget, Callback, LearnResult, LoopState, TrainingLoop, TrainSettings, train
from cartpole.training.callbacks import (
    BudgetCallback,
    CheckpointCallback,
    CheckpointSchedule,
    EvalCallback,
    MetricsCallback,
    ProgressCallback,
    StatusCallback,
    StopWhenSolved,
    TensorBoardCallback,
)


class Constant:
    """A policy that always pushes one way."""

    def __init__(self, action: int):
        self.action = action

    def act(self, observations: np.ndarray) -> np.ndarray:
        return np.full(len(observations), self.action, dtype=np.int64)


class FakeLearner:
    """Each learn() is 10 env steps and finishes one episode of return 10 * call number."""

    def __init__(self, steps: int = 10, per_generation: bool = False):
        self.calls, self.steps, self.per_generation = 0, steps, per_generation

    def learn(self) -> LearnResult:
        self.calls += 1
        scalars = {"train/loss": 1.0 / self.calls, "train/epsilon": 0.5}
        if self.per_generation:
            return LearnResult(
                self.steps,
                scalars={"train/mean_return": float(self.calls)},
                summarized_episodes=2,
                log_scalars=True,
            )
        return LearnResult(self.steps, [10.0 * self.calls], [self.steps], scalars)

    def policy(self) -> Constant:
        return Constant(0)

    def state_dict(self, resume: bool) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
        return {"w": torch.tensor([float(self.calls)])}, {"calls": self.calls, "resume": resume}

    def load_state_dict(self, tensors: dict[str, torch.Tensor], data: dict[str, Any]) -> None:
        self.calls = int(data["calls"])


class InterruptedAt(FakeLearner):
    """Asks its loop to stop (as the SIGINT handler does) during its ``at``-th learn()."""

    def __init__(self, at: int, per_generation: bool = False):
        super().__init__(per_generation=per_generation)
        self.at = at
        self.loop: TrainingLoop | None = None

    def learn(self) -> LearnResult:
        if self.calls + 1 == self.at and self.loop is not None:
            self.loop.request_stop(StopReason.INTERRUPTED, "interrupted (SIGINT)")
        return super().learn()


def run_until_stopped(loop: TrainingLoop) -> LoopState:
    """Drive ``loop`` as the engine drives each seed's loop (start; each learn() result counted,
    until a callback or a stop request ends training; end); its final counters."""
    learner = loop.learner
    assert isinstance(learner, FakeLearner)
    loop.start(time.perf_counter())
    while loop.state.stop_reason is None:
        loop.advance(learner.learn(), time.perf_counter())
    loop.end(time.perf_counter())
    return loop.state


class StopAfter(Callback):
    def __init__(self, steps: int):
        self.steps = steps

    def on_step(self, loop: TrainingLoop, result: LearnResult) -> bool:
        return loop.state.iterations < self.steps


def report(mean: float, episodes: int = 100) -> EvalReport:
    return EvalReport(
        env_id="CartPole-v1",
        simulator="gymnasium",
        returns=[mean] * episodes,
        lengths=[int(mean)] * episodes,
        seeds=list(range(episodes)),
        threshold=475.0,
        max_episode_steps=500,
    )


@pytest.fixture
def run(tmp_path) -> RunDir:
    return RunDir.create(tmp_path, "CartPole-v1", "cem", 0)


# --- the loop itself ------------------------------------------------------------------------------


def test_loop_counts_and_stops_when_a_callback_says_so():
    state = run_until_stopped(TrainingLoop(FakeLearner(), [StopAfter(3)]))
    assert (state.env_steps, state.episodes, state.iterations) == (30, 3, 3)
    assert list(state.recent_returns) == [10.0, 20.0, 30.0]
    assert state.stop_reason == StopReason.CALLBACK and state.stop_detail == "stopped by a callback"


def test_request_stop_finishes_the_step():
    learner = InterruptedAt(2)
    loop = learner.loop = TrainingLoop(learner, [StopAfter(100)])
    assert run_until_stopped(loop).stop_reason == StopReason.INTERRUPTED
    assert loop.state.stop_detail == "interrupted (SIGINT)"
    assert loop.state.env_steps == 20  # the step in progress is finished, then it stops


def test_a_failing_learning_step_is_recorded_as_the_runs_failure(monkeypatch, tmp_path):
    monkeypatch.setattr(LinearPopulation, "learn", lambda self: 1 / 0)
    with pytest.raises(ZeroDivisionError):
        train("cem", overrides={"population": 8}, budget="3gen", runs_dir=tmp_path)
    (folder,) = tmp_path.iterdir()
    status = RunDir.open(folder).status()
    assert status["state"] == "failed" and status["stop_reason"] == StopReason.FAILED
    assert status["stop_detail"] == "failed: ZeroDivisionError: division by zero"


# --- budget ---------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("budget", "iterations", "unit"),
    [
        (Budget(env_steps=45), 5, "env steps"),
        (Budget(episodes=2), 2, "episodes"),
        (Budget(iterations=4), 4, "iterations"),
    ],
)
def test_budget_stops_at_the_first_limit_reached(budget, iterations, unit):
    state = run_until_stopped(TrainingLoop(FakeLearner(), [BudgetCallback(budget)]))
    assert state.iterations == iterations
    assert state.stop_reason == StopReason.BUDGET and unit in (state.stop_detail or "")


def test_budget_in_seconds():
    loop = TrainingLoop(FakeLearner(), [BudgetCallback(Budget(seconds=0.05))])
    state = run_until_stopped(loop)
    assert state.elapsed >= 0.05 and "seconds" in (state.stop_detail or "")


def test_a_budget_passed_by_whole_generations_says_how_far_it_went(tmp_path):
    """CEM plays whole generations: a 3-episode budget plays one (8 candidates, an episode each), and
    the stop says so instead of "budget reached (3 episodes)" alone."""
    from cartpole.training import train

    settings = {"population": "8", "episodes_per_candidate": "1"}
    outcome = train(
        "cem", seed=0, budget="3ep", overrides=settings, stop_when_solved=False, runs_dir=tmp_path
    )
    assert outcome.state.episodes == 8
    assert outcome.state.stop_detail == (
        "budget reached (3 episodes; 8 episodes in all: cem learns in whole generations)"
    )
    exact = train("cem", seed=0, budget="8ep", overrides=settings, stop_when_solved=False, runs_dir=tmp_path)
    assert exact.state.stop_detail == "budget reached (8 episodes)"


def test_budget_counts_sessions_before_a_resume():
    state = LoopState(env_steps=40, iterations=4)
    loop = TrainingLoop(FakeLearner(), [BudgetCallback(Budget(env_steps=50))], state)
    assert run_until_stopped(loop).iterations == 5


def test_a_resume_whose_budget_is_spent_takes_no_step():
    """Killed after its last step but before its verdict: the resumed loop only ends."""
    learner = FakeLearner()
    state = run_until_stopped(
        TrainingLoop(learner, [BudgetCallback(Budget(env_steps=50))], LoopState(env_steps=50))
    )
    assert learner.calls == 0 and state.env_steps == 50 and state.stop_reason == StopReason.BUDGET


# --- evaluation -----------------------------------------------------------------------------------


def test_eval_runs_every_n_steps_and_at_the_end():
    settings = TrainSettings(eval_every=25, eval_screen_episodes=3)
    evaluations: list[EvalReport] = []

    class Spy(Callback):
        def on_eval(self, loop: TrainingLoop, report: EvalReport) -> bool:
            evaluations.append(report)
            return True

    callbacks = [
        BudgetCallback(Budget(env_steps=60)),
        EvalCallback(env_info("CartPole-v1"), 0, settings),
        Spy(),
    ]
    state = run_until_stopped(TrainingLoop(FakeLearner(), callbacks))
    # at 30 and 60 steps (every >= 25 steps); nothing new to judge at the end
    assert state.evaluations == len(evaluations) >= 2
    assert all(r.episodes == 3 and r.mean < 20 for r in evaluations)  # always-left falls fast
    assert len({r.seeds[0] for r in evaluations}) == len(evaluations)  # fresh seeds each time
    assert all(r.seeds[0] >= 2**32 for r in evaluations)  # never a training seed
    assert state.best_eval_mean == max(r.mean for r in evaluations)


def test_eval_screen_below_threshold_skips_the_full_evaluation(monkeypatch):
    calls: list[tuple[int, str]] = []
    screen_mean = 100.0

    def fake_evaluate(policy, env_id, episodes, seed=None, *, simulator="gymnasium"):
        calls.append((episodes, simulator))
        return report(screen_mean if simulator == "fast" else 500.0, episodes)

    monkeypatch.setattr("cartpole.training.callbacks.evaluate", fake_evaluate)
    callback = EvalCallback(env_info("CartPole-v1"), 0, TrainSettings(eval_screen_episodes=7))
    loop = TrainingLoop(FakeLearner(), [callback])
    assert callback.evaluate(loop).episodes == 7  # screen at 100 < 475: no full evaluation
    assert calls == [(7, "fast")]
    screen_mean = 480.0
    final = callback.evaluate(loop)  # the screen passes: the full evaluation decides
    assert final.solved and calls[1:] == [(7, "fast"), (100, "gymnasium")]


def test_confirm_solves_plays_a_passing_evaluation_again_and_reports_the_lower(monkeypatch):
    calls: list[tuple[int, int, str]] = []
    full_means: list[float] = []

    def fake_evaluate(policy, env_id, episodes, seed=None, *, simulator="gymnasium"):
        calls.append((episodes, seed, simulator))
        return report(500.0 if simulator == "fast" else full_means.pop(0), episodes)

    monkeypatch.setattr("cartpole.training.callbacks.evaluate", fake_evaluate)
    settings = TrainSettings(eval_screen_episodes=7, confirm_solves=True)
    callback = EvalCallback(env_info("CartPole-v1"), 0, settings)
    loop = TrainingLoop(FakeLearner(), [callback])
    full_means[:] = [480.0, 470.0]  # passed once by luck: not solved
    first = callback.evaluate(loop)
    assert first.mean == 470.0 and not first.solved
    (_, _, fast), (_, full, where), (episodes, again, there) = calls
    assert (fast, where, there, episodes) == ("fast", "gymnasium", "gymnasium", 100)
    assert again == full + 100  # the next 100 episode seeds of the full evaluation's stream
    full_means[:] = [470.0]  # a full evaluation that fails is not played again
    assert callback.evaluate(loop).mean == 470.0 and len(calls) == 5
    full_means[:] = [480.0, 490.0]  # both pass: solved, with the lower mean
    solved = callback.evaluate(loop)
    assert solved.solved and solved.mean == 480.0 and len(calls) == 8


def test_stop_when_solved():
    loop = TrainingLoop(FakeLearner(), [StopWhenSolved()])
    assert loop.record_eval(report(300.0)) is True
    assert loop.record_eval(report(480.0, episodes=20)) is True  # 20 episodes cannot solve
    assert loop.record_eval(report(480.0)) is False
    assert loop.state.stop_reason == StopReason.SOLVED and loop.state.solved
    assert loop.state.evaluations == 3 and loop.state.best_eval_mean == 480.0


# --- checkpoints ----------------------------------------------------------------------------------


def test_checkpoints_latest_every_k_best_and_solved(run):
    spec = get_agent("cem")
    meta = {"agent": "cem", "env_id": "CartPole-v1", "seed": 0, "preset": "default", "config": {}}
    saves: list[tuple[str, int]] = []

    checkpoints = Recorded(run, spec, meta, only_every(env_steps=30), saves=saves)
    loop = TrainingLoop(FakeLearner(), [StopAfter(7), checkpoints])
    run_until_stopped(loop)
    assert latest_steps(saves) == [0, 30, 60, 70]  # at start, every 30 steps, and at the end
    latest = load_checkpoint(run.checkpoint_path("latest"))
    assert latest.meta["step"] == 70 and latest.meta["resumable"] is True
    assert latest.meta["loop"]["iterations"] == 7 and latest.meta["learner"]["calls"] == 7
    assert latest.meta["loop"]["stop_reason"] == "callback"  # a resume knows training was complete

    assert not run.checkpoint_path("best").exists()
    loop.record_eval(report(200.0))
    loop.record_eval(report(100.0))  # worse: best stays
    best = load_checkpoint(run.checkpoint_path("best"))
    assert best.meta["resumable"] is False and run.best_eval_report()["mean"] == 200
    assert not (run.path / "eval.json").exists()  # in-training evaluations are not the verdict
    assert not run.checkpoint_path("solved").exists()
    loop.learner.calls = 99
    loop.record_eval(report(490.0))
    loop.learner.calls = 100
    loop.record_eval(report(500.0))  # a later solve does not replace the first
    assert load_checkpoint(run.checkpoint_path("solved")).meta["learner"]["calls"] == 99
    assert load_checkpoint(run.checkpoint_path("best")).meta["learner"]["calls"] == 100


class Recorded(CheckpointCallback):
    """Notes (name, env steps) of every save."""

    def __init__(self, *args: Any, saves: list[tuple[str, int]], **kwargs: Any):
        super().__init__(*args, **kwargs)
        self.saves = saves

    def save(self, loop: TrainingLoop, name: str, resume: bool) -> None:
        self.saves.append((name, loop.state.env_steps))
        super().save(loop, name, resume)


def only_every(env_steps: int = 0, seconds: float = 1e9, fraction: float = 1.0, budget: Budget | None = None):
    return CheckpointSchedule(budget or Budget(env_steps=10**9), fraction, seconds, env_steps)


def latest_steps(saves: list[tuple[str, int]]) -> list[int]:
    return [step for name, step in saves if name == "latest"]


@pytest.mark.parametrize(
    ("budget", "steps"),
    [
        (Budget(env_steps=100), [0, 28, 56, 84, 105]),  # at start, every 25% of 100 steps (7 a call)
        (Budget(iterations=8), [0, 14, 28, 42, 56]),  # at start, every 2 of 8 iterations
    ],
)
def test_latest_every_share_of_the_budget(run, budget, steps):
    saves: list[tuple[str, int]] = []
    schedule = only_every(fraction=0.25, budget=budget)
    checkpoints = Recorded(run, get_agent("cem"), {"agent": "cem"}, schedule, saves=saves)
    run_until_stopped(TrainingLoop(FakeLearner(steps=7), [BudgetCallback(budget), checkpoints]))
    assert latest_steps(saves) == steps


def test_latest_every_few_seconds_of_wall_time(run):
    class Slow(FakeLearner):
        def learn(self) -> LearnResult:
            time.sleep(0.02)
            return super().learn()

    saves: list[tuple[str, int]] = []
    checkpoints = Recorded(run, get_agent("cem"), {"agent": "cem"}, only_every(seconds=0.05), saves=saves)
    run_until_stopped(TrainingLoop(Slow(), [StopAfter(20), checkpoints]))  # 0.4 s or more
    assert 4 <= len(latest_steps(saves)) - 1 <= 20  # besides the save at the end


def test_default_checkpoint_cadence_is_a_tenth_of_the_budget_and_a_minute():
    from cartpole.agents.presets import preset_names
    from cartpole.agents.registry import agent_names
    from cartpole.training.config import resolve_config

    for agent in agent_names():
        for preset in preset_names(agent):
            _, settings = resolve_config(agent, get_agent(agent).config_cls, preset)
            schedule = CheckpointSchedule.from_settings(Budget(env_steps=1), settings)
            assert schedule.fraction <= 0.1 and schedule.seconds <= 60, (agent, preset)


def test_latest_checkpoint_writes_pending_metric_rows_first(run):
    """A kill -9 right after ``latest`` is saved finds every metric row up to its step on disk."""
    metrics = MetricsCallback(run, flush_seconds=1e12)  # never on time: only the checkpoint writes
    schedule = only_every(env_steps=20)
    checkpoints = CheckpointCallback(run, get_agent("cem"), {"agent": "cem"}, schedule, metrics=metrics)
    seen: list[tuple[int, list[int]]] = []

    class KillAfterLatest(Callback):
        def on_step(self, loop: TrainingLoop, result: LearnResult) -> bool:
            step = load_checkpoint(run.checkpoint_path("latest")).meta["step"]  # written at start
            if step == 0:
                return True
            seen.append((step, [r["step"] for r in run.metrics()]))
            raise KeyboardInterrupt  # as abrupt as it gets in-process: on_end still runs, but too late

    loop = TrainingLoop(FakeLearner(per_generation=True), [metrics, checkpoints, KillAfterLatest()])
    with pytest.raises(KeyboardInterrupt):
        run_until_stopped(loop)
    assert seen == [(20, [10, 20])]


# --- metrics --------------------------------------------------------------------------------------


def test_metrics_rows_and_sps(run):
    metrics = MetricsCallback(run)
    loop = TrainingLoop(FakeLearner(), [StopAfter(3), metrics])
    run_until_stopped(loop)
    rows = run.metrics()
    assert [r["train/episode_return"] for r in rows] == [10.0, 20.0, 30.0]
    assert [(r["step"], r["episode"]) for r in rows] == [(10, 1), (20, 2), (30, 3)]
    assert rows[0]["train/episode_length"] == 10 and rows[0]["train/epsilon"] == 0.5
    assert rows[-1]["train/loss"] == pytest.approx(1 / 3)
    assert all("time" in r for r in rows) and any("time/sps" in r for r in rows)

    metrics.on_eval(loop, report(480.0))
    metrics.on_end(loop)
    eval_row = run.metrics()[-1]
    assert eval_row["eval/mean_return"] == 480 and eval_row["eval/solved"] is True
    assert eval_row["eval/episodes"] == 100 and eval_row["eval/std_return"] == 0


def test_metrics_per_generation_rows(run):
    learner = InterruptedAt(1, per_generation=True)
    loop = learner.loop = TrainingLoop(learner, [StopAfter(2), MetricsCallback(run)])
    run_until_stopped(loop)
    rows = run.metrics()
    assert [(r["train/iteration"], r["train/mean_return"], r["episode"]) for r in rows] == [(1, 1.0, 2)]


def test_status_stays_running_with_counters_and_the_stop_reason(run):
    """The loop's end is not the run's end: only the session writes an end state (after the verdict)."""
    with LiveStatus(run) as live:
        run_until_stopped(
            TrainingLoop(FakeLearner(), [BudgetCallback(Budget(env_steps=30)), StatusCallback(live)])
        )
    status = run.status()
    assert status["state"] == "running" and status["env_steps"] == 30
    assert status["stop_reason"] == "budget" and status["stop_detail"] == "budget reached (30 env steps)"
    assert status["pid"] == os.getpid() and status["host"] and status["heartbeat"] > 0


# --- progress -------------------------------------------------------------------------------------


class FakeTerminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_progress_plain_lines_when_not_a_terminal():
    stream = io.StringIO()
    progress = ProgressCallback(Budget(env_steps=50), "step", stream)
    progress.PLAIN_SECONDS = 0.0
    loop = TrainingLoop(FakeLearner(), [BudgetCallback(Budget(env_steps=50)), progress])
    loop.record_eval(report(123.0, episodes=10))
    run_until_stopped(loop)
    lines = stream.getvalue().splitlines()
    assert len(lines) == 5 and "\x1b" not in stream.getvalue()
    assert "50/50 steps" in lines[-1] and "steps/s" in lines[-1]
    assert "return 50 (mean100 30.0)" in lines[-1] and "eval 123.0/10ep" in lines[-1]
    assert "epsilon 0.5" in lines[-1] and "loss 0.2" in lines[-1]


def test_progress_generations_and_time_budgets_label_their_unit():
    loop = TrainingLoop(FakeLearner(per_generation=True), [])
    loop.state.scalars["train/mean_return"] = 42.0
    progress = ProgressCallback(Budget(iterations=9), "generation")
    assert progress.total_and_done(loop)[2] == "generations"
    assert "generation mean return 42.0" in progress.describe(loop)
    assert ProgressCallback(Budget(seconds=9), "step").total_and_done(loop)[2] == "s"


def test_progress_bar_on_a_terminal():
    stream = FakeTerminal()
    progress = ProgressCallback(Budget(env_steps=50), "step", stream)
    run_until_stopped(TrainingLoop(FakeLearner(), [BudgetCallback(Budget(env_steps=50)), progress]))
    final = stream.getvalue().split("\r")[-1]  # what the terminal shows at the end
    assert "training" in final and "50/50" in final and "steps/s" in final
    assert "return 50 (mean100 30.0)" in final  # on its own line, so the bar keeps its room


# --- tensorboard ----------------------------------------------------------------------------------


def test_tensorboard_mirrors_the_metric_rows(run):
    pytest.importorskip("tensorboard")
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    metrics = MetricsCallback(run)
    board = TensorBoardCallback(run, metrics)
    loop = TrainingLoop(FakeLearner(), [StopAfter(3), metrics, board])
    run_until_stopped(loop)
    events = EventAccumulator(str(run.path / "tensorboard"))
    events.Reload()
    returns = events.Scalars("train/episode_return")
    assert [(e.step, e.value) for e in returns] == [(10, 10.0), (20, 20.0), (30, 30.0)]
    assert "train/loss" in events.Tags()["scalars"]


def test_tensorboard_logs_the_settings_at_a_new_start_only(run, tmp_path):
    """A resume (a loop that goes on from a step) keeps the hyperparameters and command its run
    started with, and adds none: TensorBoard would show one run's settings twice."""
    pytest.importorskip("tensorboard")
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    record = {"agent": "cem", "seed": 0, "config": {"population": 8}, "command": ["cartpole", "train", "cem"]}
    metrics = MetricsCallback(run)
    run_until_stopped(
        TrainingLoop(FakeLearner(), [StopAfter(2), metrics, TensorBoardCallback(run, metrics, record)])
    )
    metrics = MetricsCallback(run)
    resumed = TensorBoardCallback(run, metrics, record | {"command": ["cartpole", "train", "--resume"]})
    run_until_stopped(TrainingLoop(FakeLearner(), [StopAfter(4), metrics, resumed], LoopState(env_steps=20)))
    events = EventAccumulator(str(run.path / "tensorboard"))
    events.Reload()
    assert list(events.PluginTagToContent("hparams")) == [
        "_hparams_/experiment", "_hparams_/session_start_info", "_hparams_/session_end_info"
    ]  # fmt: skip
    (command,) = events.Tensors("command/text_summary")
    assert command.tensor_proto.string_val == [b"    cartpole train cem"]
    other = RunDir.create(tmp_path / "other", "CartPole-v1", "cem", 1)
    metrics = MetricsCallback(other)
    run_until_stopped(
        TrainingLoop(FakeLearner(), [StopAfter(1), metrics, TensorBoardCallback(other, metrics)])
    )
    with pytest.raises(KeyError):  # no record given: no settings
        EventAccumulator(str(other.path / "tensorboard")).Reload().PluginTagToContent("hparams")


def test_tensorboard_missing_gives_the_install_line(monkeypatch, run):
    import builtins

    real_import = builtins.__import__

    def no_tensorboard(name, *args, **kwargs):
        if name == "tensorboard":
            raise ImportError(name)
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_tensorboard)
    from cartpole.training import ConfigError

    with pytest.raises(ConfigError, match=r"cartpole\[tensorboard\]"):
        TensorBoardCallback(run, MetricsCallback(run))
