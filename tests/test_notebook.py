"""The notebook API (cartpole.train, open_run, show): what a notebook displays, and a real kernel
running it (nbclient)."""

from __future__ import annotations

import base64
import json
import re
from pathlib import Path

import numpy as np
import pytest
import torch

import cartpole
import cartpole.training
from cartpole.evaluation import EvalReport, evaluate
from cartpole.notebook import Animation, Plot, Run
from cartpole.notebook.animation import ShowError
from cartpole.runs import CheckpointError, RunError

PNG = b"\x89PNG"


class Balancer:
    """A linear controller that balances CartPole, with scores whose argmax is its action."""

    weights = np.array([0.05, 0.3, 1.0, 0.3])

    def scores(self, observations: np.ndarray) -> np.ndarray:
        push = np.asarray(observations) @ self.weights
        return np.stack([-push, push], axis=1)

    def act(self, observations: np.ndarray) -> np.ndarray:
        return self.scores(observations).argmax(axis=1)


class AlwaysLeft:
    def act(self, observations: np.ndarray) -> np.ndarray:
        return np.zeros(len(observations), dtype=np.int64)


def player_data(animation: Animation) -> dict:
    """The episodes the canvas player was given (the JSON argument of its function)."""
    match = re.search(
        r'\}\)\("cartpole-show-[0-9a-f]+", (\{.*\})\);\s*</script>$', animation._repr_html_(), re.S
    )
    assert match, "the player's data is not where the player reads it"
    return json.loads(match.group(1))


# -- a run -----------------------------------------------------------------------------------------


class StopHere(Exception):
    pass


def spy_on_training(monkeypatch: pytest.MonkeyPatch, *, fail: bool) -> list[int]:
    """The torch thread count each training of ``cartpole.train`` starts with (and, with ``fail``, a
    training that raises at once)."""
    seen: list[int] = []
    real = cartpole.training.train

    def spy(*args, **kwargs):
        seen.append(torch.get_num_threads())
        if fail:
            raise StopHere
        return real(*args, **kwargs)

    monkeypatch.setattr(cartpole.training, "train", spy)
    return seen


def test_train_computes_on_one_torch_thread_and_gives_the_callers_count_back(monkeypatch, tmp_path):
    """As `cartpole train` does on state observations: one thread while training (a busy core
    stalls no other thread), and the notebook's own setting again after."""
    seen = spy_on_training(monkeypatch, fail=False)
    torch.set_num_threads(3)
    run = cartpole.train("cem", seed=0, runs_dir=tmp_path, progress=False, budget="2gen")
    assert seen == [1] and torch.get_num_threads() == 3
    assert run.report is not None


@pytest.mark.parametrize(("env_id", "during"), [("CartPole-v1", 1), ("cartpole/CartPolePixels-v1", 3)])
def test_train_gives_the_callers_thread_count_back_when_training_fails(env_id, during, monkeypatch, tmp_path):
    """On images the count is left as it is (a conv net keeps every core busy), as the CLI leaves it;
    either way the caller's count is back after an exception."""
    seen = spy_on_training(monkeypatch, fail=True)
    torch.set_num_threads(3)
    with pytest.raises(StopHere):
        cartpole.train("dqn", env_id, runs_dir=tmp_path, progress=False)
    assert seen == [during] and torch.get_num_threads() == 3


def test_train_returns_a_run_that_shows_its_verdict(tmp_path: Path) -> None:
    run = cartpole.train("cem", seed=0, runs_dir=tmp_path, progress=False, population=32)
    assert isinstance(run, Run) and run.path.parent == tmp_path
    assert (run.agent, run.env_id, run.seed) == ("cem", "CartPole-v1", 0)
    config = json.loads((run.path / "config.json").read_text())
    assert config["config"]["population"] == 32  # keyword settings override the preset, as --set
    report = run.report
    assert report is not None and run.verdict == report.verdict and run.solved == report.solved
    page = run._repr_html_()
    for shown in ("cem", "CartPole-v1", report.verdict.replace(">", "&gt;"), "env steps"):
        assert shown in page
    assert report.verdict in repr(run)


def test_open_run_refuses_a_folder_that_is_no_run(tmp_path: Path) -> None:
    with pytest.raises(RunError, match="is not a run folder"):
        cartpole.open_run(tmp_path)


def test_plot_is_an_inline_png_of_the_learning_curve(cem_run: Path, tmp_path: Path) -> None:
    plot = cartpole.open_run(cem_run).plot()
    assert isinstance(plot, Plot) and plot._repr_png_().startswith(PNG)
    assert plot.figure.axes and plot.figure.axes[0].lines  # a curve was drawn
    assert plot.save(tmp_path / "curve.png").read_bytes().startswith(PNG)


def test_evaluate_judges_the_kept_policy_by_gymnasiums_rule(cem_run: Path) -> None:
    run = cartpole.open_run(cem_run)
    report = run.evaluate(episodes=100, seed=123)
    again = evaluate(cartpole.load_policy(str(cem_run)), "CartPole-v1", 100, seed=123)
    assert report.returns == again.returns and report.simulator == "gymnasium"
    assert report.verdict in report._repr_html_().replace("&gt;", ">")


def test_a_report_shows_its_verdict_colored_by_the_outcome() -> None:
    def report(returns: list[float]) -> EvalReport:
        n = len(returns)
        return EvalReport(
            "CartPole-v1", "gymnasium", returns, [int(r) for r in returns], list(range(n)), 475.0, 500
        )

    solved, failed = report([500.0] * 100), report([10.0] * 100)
    assert "SOLVED" in solved._repr_html_() and "#17804a" in solved._repr_html_()
    assert "NOT SOLVED" in failed._repr_html_() and "#b03a2e" in failed._repr_html_()


# -- show ------------------------------------------------------------------------------------------


def test_show_plays_the_episodes_evaluate_plays(cem_run: Path) -> None:
    animation = cartpole.open_run(cem_run).show(episodes=3, seed=40)
    assert animation.mode == "canvas" and animation.env_id == "CartPole-v1"
    judged = evaluate(cartpole.load_policy(str(cem_run)), "CartPole-v1", 3, seed=40)
    assert animation.returns == judged.returns  # the same start states, the same greedy play
    data = player_data(animation)
    assert [e["seed"] for e in data["episodes"]] == [40, 41, 42]
    for episode in data["episodes"]:
        assert len(episode["states"]) == len(episode["actions"]) + 1 == episode["return"] + 1
    assert data["limits"]["x_threshold"] == 2.4 and data["limits"]["fps"] == 50


def test_canvas_shows_scores_whose_argmax_is_the_action() -> None:
    data = player_data(cartpole.show(Balancer(), episodes=1, seed=3))
    episode = data["episodes"][0]
    assert episode["return"] == 500 and data["score_label"] == "scores"
    assert [int(np.argmax(s)) for s in episode["scores"]] == episode["actions"]
    assert player_data(cartpole.show(AlwaysLeft(), episodes=1))["episodes"][0]["scores"] is None


def test_each_output_has_its_own_element_and_carries_its_drawing_code() -> None:
    first, second = (cartpole.show(AlwaysLeft(), episodes=1)._repr_html_() for _ in range(2))
    ids = [re.search(r'id="(cartpole-show-[0-9a-f]+)"', page).group(1) for page in (first, second)]  # type: ignore[union-attr]
    assert ids[0] != ids[1]
    for page in (first, second):
        assert "<canvas" in page and "CartPoleDraw" in page and "requestAnimationFrame" in page


class DarkSide:
    """A stub pixel policy: pushes toward the half of its newest frame with more dark pixels."""

    def scores(self, observations: np.ndarray) -> np.ndarray:
        batch = np.asarray(observations)
        assert batch.shape[1:] == (4, 30, 100), batch.shape  # frame stacks, never states
        darkness = 255.0 - batch[:, -1].astype(np.float64)
        return np.stack([darkness[:, :, :50].sum(axis=(1, 2)), darkness[:, :, 50:].sum(axis=(1, 2))], 1) / 1e4

    def act(self, observations: np.ndarray) -> np.ndarray:
        return self.scores(observations).argmax(axis=1)


PIXELS = "cartpole/CartPolePixels-v1"


def test_show_of_a_pixel_policy_draws_what_it_sees_beside_the_scene() -> None:
    from cartpole.web.agent_view import decode_frames
    from cartpole.web.episodes import play_episode

    animation = cartpole.show(DarkSide(), PIXELS, episodes=2, seed=5)
    assert animation.mode == "canvas" and animation.view is not None
    page = animation._repr_html_()
    assert "what the agent sees" in page and "FrameStackDraw" in page and "max-width:900px" in page
    data = player_data(animation)
    for seed, episode in zip((5, 6), data["episodes"], strict=True):
        view = episode["view"]
        assert (view["stack"], view["height"], view["width"]) == (4, 30, 100)
        assert len(view["frames"]) == len(episode["states"]) == len(episode["actions"]) + 1
        # Gymnasium's CartPole and Watch's stepper move through the same states: the same frames.
        watched, _ = play_episode(DarkSide(), PIXELS, seed)
        assert np.array_equal(decode_frames(view), decode_frames(watched.view or {}))
        assert episode["actions"] == watched.actions
    assert player_data(cartpole.show(Balancer(), episodes=1))["episodes"][0]["view"] is None
    with pytest.raises(ShowError, match="mode='canvas'"):
        cartpole.show(DarkSide(), PIXELS, mode="gif")


def test_run_show_of_a_pixel_run_carries_its_view(tmp_path: Path) -> None:
    import sys

    sys.path.insert(0, str(Path(__file__).parent))
    from conftest_web import make_pixel_run

    run = cartpole.open_run(tmp_path / make_pixel_run(tmp_path))
    data = player_data(run.show(episodes=1, seed=2))
    (episode,) = data["episodes"]
    assert episode["view"]["stack"] == 4 and len(episode["view"]["frames"]) == len(episode["states"])
    assert episode["scores"] and data["env_id"] == PIXELS


def test_show_takes_a_checkpoint_file_with_its_agents_score_label(cem_run: Path) -> None:
    animation = cartpole.show(cem_run / "checkpoints" / "best.pt", episodes=1)
    assert animation.env_id == "CartPole-v1" and animation.score_label != "scores"
    assert len(animation.episodes) == 1


def test_gif_mode_embeds_a_looping_gif_with_the_episodes() -> None:
    animation = cartpole.show(AlwaysLeft(), episodes=2, mode="gif")
    assert animation.gif is not None and animation.gif.startswith(b"GIF89a")
    import io

    from PIL import Image

    image = Image.open(io.BytesIO(animation.gif))
    # both episodes (each about 10 steps, plus its start frame), every other frame of 50 fps
    assert 8 <= image.n_frames <= 16 and image.size[0] == 300
    page = animation._repr_html_()
    assert base64.b64encode(animation.gif).decode() in page and "<img" in page


def test_other_envs_show_as_gif_and_refuse_the_canvas() -> None:
    class Swing:
        def act(self, observations: np.ndarray) -> np.ndarray:
            return np.where(np.asarray(observations)[:, 5] > 0, 2, 0)  # push with the swing

    animation = cartpole.show(Swing(), "Acrobot-v1", episodes=1)
    assert animation.mode == "gif" and animation.gif is not None and len(animation.returns) == 1
    with pytest.raises(ShowError, match="draws CartPole only"):
        cartpole.show(Swing(), "Acrobot-v1", mode="canvas")


@pytest.mark.parametrize(
    ("agent", "kwargs", "message"),
    [
        (AlwaysLeft(), {"episodes": 0}, "episodes must be between 1 and"),
        (AlwaysLeft(), {"mode": "video"}, "mode must be auto, canvas or gif"),
        (object(), {}, "cannot show a object"),
    ],
)
def test_show_refuses_bad_requests_in_one_line(agent: object, kwargs: dict, message: str) -> None:
    with pytest.raises(ShowError, match=message) as err:
        cartpole.show(agent, **kwargs)  # type: ignore[arg-type]
    assert "\n" not in str(err.value)


def test_show_of_a_missing_checkpoint_says_so(tmp_path: Path) -> None:
    with pytest.raises((CheckpointError, RunError)):
        cartpole.show(tmp_path / "nothing.pt")


# -- in a real kernel ------------------------------------------------------------------------------


def test_a_notebook_trains_and_shows_inline(tmp_path: Path) -> None:
    """A fresh kernel runs train, plot and show: the outputs hold a progress bar, the run's verdict,
    a PNG and the animation, and no terminal escape codes."""
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    cells = [
        "import cartpole",
        f"run = cartpole.train('cem', seed=0, runs_dir={str(tmp_path)!r})\nrun",
        "run.plot()",
        "run.show(episodes=1)",
    ]
    notebook = nbformat.v4.new_notebook(cells=[nbformat.v4.new_code_cell(c) for c in cells])
    nbclient.NotebookClient(notebook, timeout=120, kernel_name="python3").execute()
    outputs = [o for cell in notebook.cells for o in cell.outputs]
    assert not [o for o in outputs if o.output_type == "error"]
    html = [o.data["text/html"] for o in outputs if "text/html" in o.get("data", {})]
    assert any("<progress" in page for page in html)  # the bar, updated in place
    assert any("SOLVED" in page and "CartPole-v1" in page for page in html)
    assert any("image/png" in o.get("data", {}) for o in outputs)
    assert any("cartpole-show-" in page for page in html)
    streams = "".join(o.get("text", "") for o in outputs if o.output_type == "stream")
    assert "\x1b[" not in streams
