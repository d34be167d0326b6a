"""A run as a folder to publish on a model hub (Hugging Face's): a model card and what it describes.

The folder is laid out as a run folder is, so that ``cartpole.load_policy(FOLDER)`` and ``cartpole
eval FOLDER`` read it back: ``config.json``, ``eval.json`` (the verdict) and the kept checkpoint
under ``checkpoints/``, beside ``README.md`` (the model card), ``model.onnx`` (the greedy policy,
:mod:`~cartpole.export.onnx_graph`) and ``replay.mp4`` (the verdict's first episode, where the video
extra is installed). The card's YAML front matter is what the hub reads, as Stable-Baselines3's and
the RL Zoo's cards give it: ``library_name``, ``tags`` and a ``model-index`` whose ``mean_reward`` is
the verdict's ``"mean +/- std"``.

The folder is made beside its destination under a temporary name and renamed into place when
complete: a failed export leaves nothing half written.
"""

from __future__ import annotations

import json
import secrets
import shlex
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cartpole.agents.registry import OpenedPolicy, open_policy
from cartpole.evaluation import EvalReport
from cartpole.export.onnx_graph import ExportError, input_dtype, require_export_extra, write_onnx
from cartpole.recording import RecordingError, check_video_path, render_episodes, write_video
from cartpole.runs import RunDir
from cartpole.runs.atomic import write_text_atomic
from cartpole.runs.run_dir import CHECKPOINTS, CONFIG, EVAL

CARD = "README.md"
ONNX_FILE = "model.onnx"
REPLAY = "replay.mp4"
LIBRARY = "cartpole"
UPLOAD_COMMAND = "hf upload USER/REPO {folder} ."
"""The one command that publishes a folder (huggingface_hub's CLI; older: ``huggingface-cli upload``)."""


@dataclass(frozen=True)
class HubFolder:
    """What :func:`write_hub_folder` wrote."""

    path: Path
    checkpoint: Path
    onnx: Path
    video: Path | None
    """None where the video extra is not installed."""
    report: EvalReport


def write_hub_folder(run: str | Path, folder: str | Path) -> HubFolder:
    """Write run folder ``run``'s kept agent, its verdict and a model card into ``folder`` (new, or
    empty); ExportError (one line) where that cannot be done."""
    folder = Path(folder)
    check_destination(folder)
    require_export_extra()
    run_dir, report = verdict_of(Path(run))
    opened = open_policy(run_dir.path)
    folder.parent.mkdir(parents=True, exist_ok=True)
    staging = folder.parent / f".{folder.name}.{secrets.token_hex(4)}.partial"
    staging.mkdir()  # with the usual mode (mkdtemp's folders are private)
    try:
        written = fill(staging, run_dir, opened, report)
        if folder.exists():
            folder.rmdir()  # empty, as checked
        staging.rename(folder)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    checkpoint, video = written
    replay = None if video is None else folder / video
    return HubFolder(folder, folder / checkpoint, folder / ONNX_FILE, replay, report)


def check_destination(folder: Path) -> None:
    """ExportError unless ``folder`` is new or an empty folder (nothing is ever written over)."""
    if folder.exists() and not folder.is_dir():
        raise ExportError(f"--hub {folder} is a file: name a new or empty folder")
    if folder.is_dir() and any(folder.iterdir()):
        raise ExportError(
            f"--hub {folder} is not empty: name a new or empty folder (nothing is written over)"
        )


def verdict_of(run: Path) -> tuple[RunDir, EvalReport]:
    """The run folder ``run`` and its verdict; ExportError for a checkpoint file or a run without one."""
    if not run.is_dir():
        raise ExportError(
            f"{run} is not a run folder: a hub folder is made from a run folder (its config.json and "
            "eval.json); give the run's folder"
        )
    run_dir = RunDir.open(run)
    data = run_dir.eval_report(strict=True)
    if data is None:
        raise ExportError(
            f"{run} has no verdict yet (eval.json), which the model card reports: let its training finish "
            f"(or `cartpole train --resume {run}`)"
        )
    return run_dir, EvalReport.from_dict(data)


def fill(staging: Path, run: RunDir, opened: OpenedPolicy, report: EvalReport) -> tuple[str, str | None]:
    """Everything the folder holds, written into ``staging``; the checkpoint's and the video's names
    in it."""
    config = run.config()
    for record in (CONFIG, EVAL):
        shutil.copyfile(run.path / record, staging / record)
    checkpoint = Path(CHECKPOINTS) / opened.path.name
    (staging / CHECKPOINTS).mkdir()
    shutil.copyfile(opened.path, staging / checkpoint)
    write_onnx(opened, staging / ONNX_FILE)
    video = write_replay(opened, report, staging / REPLAY)
    files = {"checkpoint": checkpoint.as_posix(), "video": None if video is None else REPLAY}
    card = model_card(config, report, files, opened.checkpoint.meta, input_dtype(opened.env).name)
    write_text_atomic(staging / CARD, card)
    return files["checkpoint"] or "", files["video"]


def write_replay(opened: OpenedPolicy, report: EvalReport, out: Path) -> Path | None:
    """The verdict's first episode as an MP4 at ``out``; None where the video extra is not installed."""
    try:
        check_video_path(out)
    except RecordingError:
        return None
    recording = render_episodes(opened.policy, opened.env, 1, report.seeds[0])
    return write_video(recording.frames, out, recording.fps)


def model_name(config: dict[str, Any]) -> str:
    """``<agent>-<env id>``, the repository name SB3's and the RL Zoo's cards use (``/``: ``-``)."""
    return f"{config['agent']}-{config['env_id']}".replace("/", "-").replace(":", "-")


def front_matter(config: dict[str, Any], report: EvalReport) -> str:
    """The card's YAML metadata. Every string is written as a JSON string, which YAML reads as the
    same string (a JSON document is YAML): no YAML library is needed to write it."""
    env_id, agent = str(config["env_id"]), str(config["agent"])
    q = json.dumps
    tags = ["reinforcement-learning", "cartpole", env_id, agent]
    lines = [
        "---",
        f"library_name: {q(LIBRARY)}",
        "tags:",
        *[f"- {q(tag)}" for tag in dict.fromkeys(tags)],
        "model-index:",
        f"- name: {q(model_name(config))}",
        "  results:",
        "  - task:",
        f"      type: {q('reinforcement-learning')}",
        f"      name: {q('reinforcement-learning')}",
        "    dataset:",
        f"      name: {q(report.env_label)}",  # with its kwargs and wrappers: never the plain env's
        f"      type: {q(env_id)}",
        "    metrics:",
        f"    - type: {q('mean_reward')}",
        f"      value: {q(f'{report.mean:.2f} +/- {report.std:.2f}')}",
        f"      name: {q('mean_reward')}",
        "      verified: false",
        "---",
    ]
    return "\n".join(lines) + "\n"


def model_card(
    config: dict[str, Any],
    report: EvalReport,
    files: dict[str, str | None],
    meta: dict[str, Any],
    observation_dtype: str = "float32",
) -> str:
    """The card: metadata, then the verdict, the replay, how it was trained and how to load it.
    ``files`` names the ``checkpoint`` and the ``video`` (None: none) in the folder."""
    name, agent, env_id = model_name(config), config["agent"], config["env_id"]
    command = config.get("command")
    trained = (
        shlex.join(str(a) for a in command) if isinstance(command, list) and command else "(not recorded)"
    )
    video = (
        f"![The verdict's first episode (seed {report.seeds[0]})]({files['video']})"
        if files["video"]
        else "No replay: the video extra (imageio-ffmpeg) was not installed when this folder was made."
    )
    settings = json.dumps(config.get("config", {}), indent=2)
    seeds = f"{report.seeds[0]}..{report.seeds[-1]}"
    spread = f"{report.mean:.2f} ± {report.std:.2f} | {report.min:g} / {report.max:g}"
    replay_row = f"| `{files['video']}` | the verdict's first episode |\n" if files["video"] else ""
    weights = "the run's checkpoint (tensors and JSON metadata: `torch.load(FILE, weights_only=True)`)"
    return f"""{front_matter(config, report)}
# {agent} on {report.env_label}

A greedy {agent} agent for `{env_id}`, trained with `{LIBRARY}` (seed {config.get("seed")}, preset
`{config.get("preset", "default")}`), kept at env step {meta.get("step")}.

## Verdict

{report.verdict}

| episodes | mean ± std | min / max | simulator | episode seeds |
| --- | --- | --- | --- | --- |
| {report.episodes} | {spread} | {report.simulator} | {seeds} |

{video}

## How it was trained

```
{trained}
```

`config.json` holds the run's settings, `eval.json` every episode of the verdict. The agent's settings:

```json
{settings}
```

## How to load it

Fetch it with `hf download USER/REPO --local-dir {name}`. With `{LIBRARY}` installed:

```
cartpole eval {name}      # a new verdict, on fresh episode seeds
```

```python
import cartpole

policy = cartpole.load_policy("{name}")
actions = policy.act(observations)  # observations [N, ...] as the env gives them -> actions [N]
```

Without it, the greedy policy is `{ONNX_FILE}`, for any ONNX runtime: `observations` `[N, ...]`
({observation_dtype}) in, `action` `[N]` and `scores` `[N, actions]` out:

```python
import numpy as np
import onnxruntime

session = onnxruntime.InferenceSession("{ONNX_FILE}")
batch = np.asarray([observation], dtype=np.{observation_dtype})  # one observation of the env
action, scores = session.run(None, {{"observations": batch}})
```

## Files

| file | what |
| --- | --- |
| `{files["checkpoint"]}` | the weights: {weights} |
| `{ONNX_FILE}` | the greedy policy as an ONNX graph, observation standardization included |
| `config.json`, `eval.json` | the run's settings and command; its verdict, every episode |
{replay_row}"""


__all__ = ["CARD", "ONNX_FILE", "REPLAY", "UPLOAD_COMMAND", "HubFolder", "model_card", "write_hub_folder"]
