"""The runs folder as the web app sees it: read-only, and only through validated names.

A run name from a URL must name a folder directly inside the runs folder, and a checkpoint name a
``.pt`` file directly inside that run's ``checkpoints/`` (a regular file: a symlinked checkpoint is
neither listed nor read). Anything else (``..``, absolute paths, separators, hidden names, symlinks)
is reported as "not found", never opened.
"""

from __future__ import annotations

import re
from dataclasses import asdict
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from cartpole.envs import env_info
from cartpole.runs import RunDir, RunError, RunSummary, displayed_state, list_runs, summarize_run
from cartpole.web.physics import scene_of

SAFE_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,199}$")


class NotFound(LookupError):
    """No such run or checkpoint (or a name that is not allowed)."""


def inside(path: Path, parent: Path) -> bool:
    try:
        path.resolve(strict=True).relative_to(parent.resolve())
    except (OSError, ValueError):
        return False
    return True


def _is_checkpoint_file(path: Path, run: RunDir) -> bool:
    """A regular file (not a symlink, dangling or not) inside the run's folder."""
    return not path.is_symlink() and path.is_file() and inside(path, run.path)


class RunsFolder:
    """Read access to ``root`` for the API."""

    def __init__(self, root: Path):
        self.root = Path(root)

    def run(self, name: str) -> RunDir:
        """The run folder called ``name``; NotFound if there is none (or the name is unsafe)."""
        if not SAFE_NAME.match(name) or ".." in name:
            raise NotFound(f"no run named {name!r}")
        path = self.root / name
        if not path.is_dir() or not inside(path, self.root):
            raise NotFound(f"no run named {name!r} in the runs folder")
        return RunDir(path)

    def checkpoint(self, run: RunDir, name: str) -> Path:
        """The checkpoint file ``name`` of ``run``; NotFound if absent or unsafe."""
        if not SAFE_NAME.match(name) or "." in name:
            raise NotFound(f"no checkpoint named {name!r}")
        path = run.checkpoint_path(name)
        if not _is_checkpoint_file(path, run):
            kept = ", ".join(str(kept) for kept in self.checkpoints(run)) or "none yet"
            raise NotFound(f"run {run.name} has no checkpoint {name!r}; it has: {kept}")
        return path

    @staticmethod
    def checkpoints(run: RunDir) -> list[str]:
        """The run's checkpoints that may be read: regular files, not links."""
        return [name for name in run.checkpoints() if _is_checkpoint_file(run.checkpoint_path(name), run)]

    def summaries(self) -> list[dict[str, Any]]:
        """Every run, newest first, each with a one-line rule for its badge (an unreadable run is
        listed with its problem); RunError if the runs folder itself cannot be listed."""
        rows = []
        for summary in list_runs(self.root):
            path = Path(summary.path)
            if path.is_symlink() and not inside(path, self.root):
                continue  # a link to elsewhere is not one of our runs
            row = _as_shown(summary)
            row["rule"] = solved_rule(RunDir(path).eval_report())
            row["watchable"] = bool(summary.env_id and scene_of(summary.env_id))
            row["has_checkpoint"] = bool(self.checkpoints(RunDir(path)))
            rows.append(row)
        return rows

    def detail(self, run: RunDir) -> dict[str, Any]:
        """Everything the Run page shows except the metrics."""
        summary = _as_shown(summarize_run(run.path))
        try:
            config = run.config()
        except RunError:
            config = None
        report = run.eval_report()
        env_id = summary.get("env_id")
        threshold = max_steps = None
        if env_id:
            try:
                info = env_info(env_id)
                threshold, max_steps = info.reward_threshold, info.max_episode_steps
            except ValueError:
                pass
        return {
            **summary,
            "config": config,
            "status": shown_status(run),
            "eval": report,
            "rule": solved_rule(report),
            "threshold": threshold,
            "max_episode_steps": max_steps,
            "watchable": bool(env_id and scene_of(env_id)),
            "scene": scene_of(env_id) if env_id else None,
            "checkpoints": [self._checkpoint_info(run, name) for name in self.checkpoints(run)],
        }

    @staticmethod
    def _checkpoint_info(run: RunDir, name: str) -> dict[str, Any]:
        try:
            stat = run.checkpoint_path(name).lstat()
        except OSError:  # removed since it was listed
            return {"name": name, "bytes": None, "modified": None}
        modified = datetime.fromtimestamp(stat.st_mtime, UTC).isoformat(timespec="seconds")
        return {"name": name, "bytes": stat.st_size, "modified": modified}


def _as_shown(summary: RunSummary) -> dict[str, Any]:
    """A run's summary for the API: no path, and a problem that names files relative to the runs
    folder ("<run>/config.json is unreadable: ..."), not where the runs folder is on this machine."""
    row = asdict(summary)
    path = row.pop("path")
    if row["problem"]:
        row["problem"] = row["problem"].replace(path, summary.name)
    return row


def shown_status(run: RunDir) -> dict[str, Any]:
    """``status.json`` with the displayed state (a run whose process died is "crashed")."""
    status = run.status()
    return {**status, "state": displayed_state(status).value}


def solved_rule(report: dict[str, Any] | None) -> str | None:
    """The rule behind the verdict in a few words, e.g. "mean 498.2 >= 475 over 100 episodes, CartPole-v1"."""
    if not report:
        return None
    try:
        mean, episodes, env_id = float(report["mean"]), int(report["episodes"]), report["env_id"]
    except (KeyError, TypeError, ValueError):
        return report.get("verdict")
    threshold = report.get("threshold")
    if threshold is None:
        return f"mean {mean:.1f} over {episodes} episodes, {env_id} (no threshold registered)"
    sign = ">=" if mean >= threshold else "<"
    return f"mean {mean:.1f} {sign} {threshold:g} over {episodes} episodes, {env_id}"
