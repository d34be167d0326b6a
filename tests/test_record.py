"""``cartpole record`` and ``cartpole eval --render``: videos rendered without a display."""

from __future__ import annotations

import builtins
import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from cartpole.cli.main import main
from cartpole.recording import RecordingError, default_video_path, render_episodes, write_video

SEED = 2**32 + 7


def test_render_episodes_frames_match_the_episodes(always_left):
    recording = render_episodes(always_left, "CartPole-v1", 2, SEED)
    assert recording.seeds == [SEED, SEED + 1]
    assert all(length < 20 for length in recording.lengths)  # pushing left fails fast
    assert recording.returns == [float(n) for n in recording.lengths]
    # each episode: its start frame, then one frame per step
    assert len(recording.frames) == sum(recording.lengths) + 2
    assert recording.frames[0].shape == (400, 600, 3) and recording.frames[0].dtype.name == "uint8"
    assert recording.fps == 50


def test_same_seed_same_episodes_as_evaluate(always_left, balancer):
    from cartpole.evaluation import evaluate

    recording = render_episodes(always_left, "CartPole-v1", 5, SEED, caption=False)
    report = evaluate(always_left, "CartPole-v1", 5, seed=SEED)
    assert recording.seeds == report.seeds and recording.lengths == report.lengths
    short = render_episodes(balancer, "CartPole-v1", 1, SEED, max_steps=5)
    assert len(short.frames) == 6 and short.lengths == [5]


def test_gif_has_the_expected_number_of_frames(always_left, tmp_path):
    recording = render_episodes(always_left, "CartPole-v1", 3, SEED)
    out = write_video(recording.frames, tmp_path / "left.gif", recording.fps)
    with Image.open(out) as gif:
        assert gif.format == "GIF" and gif.n_frames == len(recording.frames)
        assert gif.info["duration"] == 20 and gif.info["loop"] == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["left.gif"]  # no temp file left


def test_record_of_more_frames_than_memory_holds_is_one_line_before_playing(cem_run, tmp_path, capsys):
    out = tmp_path / "huge.gif"
    assert main(["record", str(cem_run), "--episodes", "10000000", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "10,000,000 episodes of up to 500 steps would hold" in err
    assert "record at most" in err and not out.exists()


def test_record_cli_writes_a_gif(cem_run, tmp_path, capsys):
    out = tmp_path / "cem.gif"
    args = ["record", str(cem_run), "--episodes", "2", "--seed", str(SEED), "--max-steps", "30"]
    assert main([*args, "--out", str(out)]) == 0
    with Image.open(out) as gif:
        assert gif.n_frames == 2 * (30 + 1)  # a solved agent lasts the 30 steps
    assert f"wrote {out}" in capsys.readouterr().out


def test_record_default_path_is_named_after_the_run(cem_run, tmp_path):
    checkpoint = cem_run / "checkpoints" / "best.pt"
    assert default_video_path(checkpoint, 5) == Path(f"{cem_run.name}-best-seed5.gif")
    assert default_video_path(tmp_path / "model.pt", 5) == Path("model-seed5.gif")


def test_mp4(always_left, tmp_path):
    pytest.importorskip("imageio_ffmpeg")
    recording = render_episodes(always_left, "CartPole-v1", 1, SEED)
    out = write_video(recording.frames, tmp_path / "left.mp4", recording.fps)
    assert out.read_bytes()[4:8] == b"ftyp"


def test_mp4_without_the_extra_names_it(cem_run, tmp_path, monkeypatch, capsys):
    real_import = builtins.__import__

    def no_ffmpeg(name, *args, **kwargs):
        if name.startswith("imageio"):
            raise ImportError(name)
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_ffmpeg)
    with pytest.raises(RecordingError, match=r"cartpole\[video\]"):
        write_video([], tmp_path / "x.mp4")
    assert main(["record", str(cem_run), "--out", str(tmp_path / "x.mp4")]) == 2
    err = capsys.readouterr().err
    assert "cartpole[video]" in err and "Traceback" not in err
    assert not (tmp_path / "x.mp4").exists()


def test_record_bad_input(cem_run, tmp_path, capsys):
    assert main(["record", str(cem_run), "--out", str(tmp_path / "x.avi")]) == 2
    assert "use a .gif or .mp4" in capsys.readouterr().err
    assert main(["record", str(cem_run), "--episodes", "0"]) == 2
    assert main(["record", str(tmp_path / "missing.pt")]) == 2


def test_eval_render_writes_the_video_of_its_first_episodes(cem_run, tmp_path, capsys, monkeypatch):
    import torch

    from cartpole.runs import load_checkpoint, save_checkpoint

    # A policy that falls fast keeps the video short: zero weights always push left.
    checkpoint = load_checkpoint(cem_run / "checkpoints" / "best.pt")
    checkpoint.tensors["params"] = torch.zeros_like(checkpoint.tensors["params"])
    weak = tmp_path / "weak.pt"
    save_checkpoint(weak, checkpoint)
    out = tmp_path / "eval.gif"
    args = ["eval", str(weak), "--episodes", "5", "--seed", str(SEED), "--json"]
    assert main([*args, "--render", str(out)]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["video"] == str(out)
    with Image.open(out) as gif:
        assert gif.n_frames == sum(report["lengths"][:3]) + 3  # its first 3 episodes

    (tmp_path / "cwd").mkdir()
    monkeypatch.chdir(tmp_path / "cwd")
    assert main(["eval", str(weak), "--episodes", "1", "--seed", "9", "--render"]) == 0
    assert (tmp_path / "cwd" / "weak-seed9.gif").is_file()  # default: in the current folder


@pytest.mark.parametrize("where", ["read-only", "under-a-file", "under-a-file-deeper"])
def test_eval_render_to_an_unwritable_file_fails_before_playing_and_names_it(
    where, cem_run, tmp_path, monkeypatch, capsys, request
):
    """`cartpole eval RUN --render /unwritable/x.gif` fails before the episodes are played (they can
    take minutes), in one line naming the target, not a temporary file."""
    import cartpole.evaluation

    if where == "read-only":  # a folder no process may write in, root included
        target = request.getfixturevalue("tmpfs")("read-only", "ro,size=64k") / "x.gif"
    else:
        (tmp_path / "file").write_text("not a folder")
        target = tmp_path / "file" / ("x.gif" if where == "under-a-file" else "sub/x.gif")

    def must_not_play(*args, **kwargs):
        raise AssertionError("episodes were played before the video's file was checked")

    monkeypatch.setattr(cartpole.evaluation, "evaluate", must_not_play)
    assert main(["eval", str(cem_run), "--episodes", "100", "--render", str(target)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    assert err.startswith(f"cartpole eval: error: {target}: ") and ".x.gif." not in err, err
    assert main(["record", str(cem_run), "--out", str(target)]) == 2  # record checks it first too
    assert str(target) in capsys.readouterr().err


class PixelLeft:
    """A pixel agent's stand-in: pushes left, and keeps what it was shown."""

    def __init__(self) -> None:
        self.seen: list[np.ndarray] = []

    def act(self, observations: np.ndarray) -> np.ndarray:
        self.seen.append(np.asarray(observations))
        return np.zeros(len(observations), dtype=np.int64)


def test_a_pixel_agent_is_recorded_on_gymnasiums_cartpole_seeing_its_frame_stacks():
    agent = PixelLeft()
    recording = render_episodes(agent, "cartpole/CartPolePixels-v1", 1, SEED)
    left = render_episodes(PixelLeft(), "CartPole-v1", 1, SEED)
    assert recording.lengths == left.lengths  # the same episode of Gymnasium's CartPole
    assert recording.frames[0].shape == (400, 600, 3)  # the screen is recorded, not the agent's frames
    assert {a.shape for a in agent.seen} == {(1, 4, 30, 100)} and agent.seen[0].dtype == np.uint8
