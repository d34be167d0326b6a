"""Fingerprints of what every agent learns, under every preset: run at two commits, equal hashes mean
the same bits.

    python benchmarks/fingerprint.py --out base.json                    # every agent and preset
    python benchmarks/fingerprint.py --out head.json --jobs 2           # two cases at a time
    python benchmarks/fingerprint.py --out ppo.json --cases ppo/default,dqn/pixels
    python benchmarks/fingerprint.py --list                             # the cases and their budgets
    python benchmarks/fingerprint.py --compare base.json head.json      # exit 1 on any difference

A case is an agent under one of its presets, on the env the preset is for (the ``acrobot`` presets on
Acrobot-v1, ``mountaincar`` on MountainCar-v0, the pixel presets on cartpole/CartPolePixels-v1, the
rest on CartPole-v1), plus DQN's default with each option the presets leave off (no double DQN, no
target network, a dueling head, MSE with 1-step rows and hard target copies, gradient norms clipped).
Each case trains a small budget (several updates and at least one evaluation) with
``stop_when_solved`` off, twice: seeds 1 and 2 as one population (``train_population``), and seed 2
as a single run (``train``). Of each seed's run folder it hashes

- ``metrics``: every row of ``metrics.jsonl`` (training episodes' returns and lengths, update metrics,
  evaluations), without the wall times (``time``, ``time/sps``);
- ``verdict``: ``eval.json``, the final verdict's episodes;
- ``latest.pt`` and ``best.pt``: each tensor on its own (dtype, shape and bytes), the learner's
  metadata (generators, counters, env states) and the loop's counters (without wall times).

``--compare`` names every hash that differs, and every one that only one file has. One torch thread
(``cartpole train``'s default), on the CPU.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import subprocess
import sys
import tempfile
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

POPULATION_SEEDS = [1, 2]
SINGLE_SEED = 2
TIMES = ("time", "time/sps")
LOOP_TIMES = ("elapsed", "solved_at_seconds")

PRESET_ENVS = {
    "acrobot": "Acrobot-v1",
    "mountaincar": "MountainCar-v0",
    "pixels": "cartpole/CartPolePixels-v1",
    "tutorial-pytorch-pixels": "cartpole/CartPolePixels-v1",
}
"""The env of each preset made for another env than CartPole-v1."""

STEP_BUDGETS = {"ppo": 4000, "a2c": 3000, "reinforce": 3000, "dqn": 2000}
"""Env steps per case, by agent: a few dozen updates of the default presets."""

PRESET_BUDGETS = {
    ("ppo", "pixels"): 1536,
    ("reinforce", "mountaincar"): 8000,
    ("reinforce", "acrobot"): 10000,
    ("dqn", "tutorial-keras"): 1000,
    ("dqn", "tutorial-pytorch"): 1000,
    ("dqn", "mountaincar"): 3000,
    ("dqn", "pixels"): 1500,
    ("dqn", "tutorial-pytorch-pixels"): 400,
}
"""Budgets that differ from the agent's: a few updates of a slow preset (pixels, big networks), or
enough steps for several updates of one that collects many per update (whole MountainCar episodes)."""

GENERATIONS = {"mountaincar": 2}
"""Generations of the linear searches by preset (default: 3)."""

DQN_VARIANTS: dict[str, dict[str, Any]] = {
    "no-double-dqn": {"double_dqn": False},
    "no-target-network": {"target_network": False},
    "dueling": {"dueling": True},
    "mse-1-step-hard-copies": {"loss": "mse", "n_step": 1, "tau": 1.0, "target_update_interval": 50},
    "gradient-clipping": {"max_grad_norm": 0.5},
}
"""DQN's default preset with options no preset combines with it."""


@dataclass(frozen=True)
class Case:
    """One agent under one preset (and settings changed from it), its env and its budget."""

    agent: str
    preset: str
    env_id: str
    budget: str
    overrides: dict[str, Any] = field(default_factory=dict)
    variant: str = ""

    @property
    def name(self) -> str:
        return f"{self.agent}/{self.preset}" + (f"+{self.variant}" if self.variant else "")


def cases() -> list[Case]:
    """Every agent under every preset, and DQN's variants."""
    from cartpole.agents.presets import preset_names
    from cartpole.agents.registry import agent_names, get_agent

    found = []
    for agent in agent_names():
        for preset in preset_names(agent):
            env_id = PRESET_ENVS.get(preset, "CartPole-v1")
            if get_agent(agent).iteration == "generation":
                found.append(Case(agent, preset, env_id, f"{GENERATIONS.get(preset, 3)}gen"))
                continue
            steps = PRESET_BUDGETS.get((agent, preset), STEP_BUDGETS[agent])
            found.append(Case(agent, preset, env_id, str(steps), {"eval_every": steps // 2}))
    steps = STEP_BUDGETS["dqn"]
    for variant, changes in DQN_VARIANTS.items():
        overrides = {"eval_every": steps // 2, **changes}
        found.append(Case("dqn", "default", "CartPole-v1", str(steps), overrides, variant))
    return found


def digest(data: bytes | str) -> str:
    return hashlib.sha256(data.encode() if isinstance(data, str) else data).hexdigest()[:16]


def json_digest(value: Any) -> str:
    return digest(json.dumps(value, sort_keys=True, allow_nan=True))


def tensor_digest(tensor: Any) -> str:
    """A tensor's dtype, shape and bytes."""
    head = f"{tensor.dtype} {list(tensor.shape)} "
    return digest(head.encode() + tensor.detach().cpu().contiguous().numpy().tobytes())


def run_hashes(run: Path) -> dict[str, str]:
    """Hashes of what a seed's run folder holds (see the module docstring), by name."""
    import torch

    rows = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines() if line]
    hashes = {
        "metrics": json_digest([{k: v for k, v in row.items() if k not in TIMES} for row in rows]),
        "verdict": json_digest(json.loads((run / "eval.json").read_text())),
    }
    for name in ("latest", "best"):
        saved = torch.load(run / "checkpoints" / f"{name}.pt", weights_only=True)
        meta = json.loads(saved["meta"])
        hashes[f"{name}.pt learner data"] = json_digest(meta.get("learner"))
        loop = {k: v for k, v in (meta.get("loop") or {}).items() if k not in LOOP_TIMES}
        hashes[f"{name}.pt loop"] = json_digest(loop)
        for key, tensor in saved["tensors"].items():
            hashes[f"{name}.pt {key}"] = tensor_digest(tensor)
    return hashes


def fingerprint(case: Case) -> dict[str, Any]:
    """Train ``case`` as a population and as a single run; the hashes of each seed's run."""
    import torch

    from cartpole.training.session import train, train_population

    torch.set_num_threads(1)
    options: dict[str, Any] = {
        "preset": case.preset,
        "overrides": dict(case.overrides),
        "budget": case.budget,
        "stop_when_solved": False,
    }
    with tempfile.TemporaryDirectory(prefix="fingerprint-") as folder:
        runs_dir = Path(folder)
        population = train_population(
            case.agent, POPULATION_SEEDS, case.env_id, runs_dir=runs_dir / "population", **options
        )
        single = train(case.agent, case.env_id, seed=SINGLE_SEED, runs_dir=runs_dir / "single", **options)
        runs = {f"population seed {s}": run_hashes(population.runs[s].path) for s in POPULATION_SEEDS}
        runs[f"single seed {SINGLE_SEED}"] = run_hashes(single.run.path)
    return {"env_id": case.env_id, "budget": case.budget, "overrides": case.overrides, "runs": runs}


def commit() -> str | None:
    """The commit of the code being fingerprinted (where the imported package lives)."""
    import cartpole

    done = subprocess.run(
        ["git", "-C", str(Path(cartpole.__file__).parent), "rev-parse", "--short", "HEAD"],
        capture_output=True,
        text=True,
    )
    return done.stdout.strip() or None


def compare(before: dict[str, Any], after: dict[str, Any]) -> list[str]:
    """One line per hash that differs between two fingerprint files, or that only one of them has."""
    lines = []
    old, new = before["cases"], after["cases"]
    for name in sorted(old.keys() | new.keys()):
        if name not in old or name not in new:
            lines.append(f"{name}: only in {'the second' if name in new else 'the first'} file")
            continue
        old_runs, new_runs = old[name]["runs"], new[name]["runs"]
        for run in sorted(old_runs.keys() | new_runs.keys()):
            left, right = old_runs.get(run, {}), new_runs.get(run, {})
            for key in sorted(left.keys() | right.keys()):
                if key not in left or key not in right:
                    where = "the second" if key in right else "the first"
                    lines.append(f"{name}, {run}: {key} only in {where}")
                elif left[key] != right[key]:
                    lines.append(f"{name}, {run}: {key} differs")
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    action = parser.add_mutually_exclusive_group(required=True)
    action.add_argument("--out", type=Path, help="write the fingerprints of the cases to this JSON file")
    action.add_argument("--compare", nargs=2, type=Path, metavar=("FIRST", "SECOND"))
    action.add_argument("--list", action="store_true", help="print the cases and their budgets")
    parser.add_argument("--cases", help="comma-separated case names (agent/preset[+variant]); default: all")
    parser.add_argument("--jobs", type=int, default=1, help="cases trained at a time, each in a process")
    args = parser.parse_args(argv)
    if args.compare:
        files = []
        for path in args.compare:
            try:
                files.append(json.loads(path.read_text()))
            except (OSError, ValueError) as err:
                parser.error(f"cannot read {path}: {err}")
        differences = compare(*files)
        for line in differences:
            print(line)
        compared = len(files[0]["cases"].keys() & files[1]["cases"].keys())
        print(f"{len(differences)} difference(s) in {compared} case(s) compared")
        return 1 if differences else 0
    if args.jobs < 1:
        parser.error("--jobs must be at least 1")
    chosen = cases()
    if args.cases:
        names = args.cases.split(",")
        unknown = sorted(set(names) - {case.name for case in chosen})
        if unknown:
            parser.error(f"unknown case {unknown[0]!r}; --list names them")
        chosen = [case for case in chosen if case.name in names]
    if args.list:
        for case in chosen:
            print(f"{case.name}: {case.env_id}, budget {case.budget}, {case.overrides}")
        return 0
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        found = dict(zip([case.name for case in chosen], pool.map(fingerprint, chosen), strict=True))
    args.out.write_text(json.dumps({"commit": commit(), "cases": found}, indent=1, sort_keys=True) + "\n")
    print(f"{len(found)} case(s) fingerprinted into {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
