"""Re-run chosen benchmarks and rewrite their tables, benchmarks/README.md and the README's "How fast".

    python benchmarks/run.py --list                   # every table: its command and about how long
    python benchmarks/run.py --quick                  # the tables that take minutes
    python benchmarks/run.py --all                    # every table (hours; pixels and gpu when they can)
    python benchmarks/run.py time-to-solve population # named tables
    python benchmarks/run.py --quick --note "shared with other jobs"   # said on each table's machine line
    python benchmarks/run.py --assemble               # only rewrite the READMEs from benchmarks/results/
    python benchmarks/run.py --check                  # exit 1 if a README differs from benchmarks/results/
    python benchmarks/run.py --smoke --all            # every script on a tiny setting, into a /tmp folder
    python benchmarks/run.py kernels --results-dir D  # tables and READMEs into D, the repository's untouched

Each table's script writes ``benchmarks/results/NAME.md`` (the table under a line with its command,
date, commit and machine) and ``NAME.json`` (the same, its raw results and a summary); see
``table_file.py``. This script then copies each ``NAME.md`` into ``benchmarks/README.md`` between
``<!-- table: NAME -->`` and ``<!-- end table: NAME -->``, and writes the README's "How fast" table
from the summaries, between ``<!-- how-fast -->`` and ``<!-- end how-fast -->``: so neither can
drift from the tables. A table whose summary holds ``"readme": [{"measure", "ours", "peer", "ratio",
"verified"}, ...]`` gives its own README rows (a new table needs nothing else here but its entry).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shlex
import subprocess
import sys
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cpu import AVX2_SETTINGS
from table_file import BENCHMARKS, RESULTS_DIR, describe_machine

ROOT = BENCHMARKS.parent
BENCHMARKS_README = BENCHMARKS / "README.md"
README = ROOT / "README.md"
TABLE_BLOCK = re.compile(r"(<!-- table: ([a-z0-9-]+) -->\n)(.*?)(<!-- end table: \2 -->)", re.S)
HOW_FAST_BLOCK = re.compile(r"(<!-- how-fast[^\n]*-->\n)(.*?)(<!-- end how-fast -->)", re.S)


@dataclass(frozen=True)
class Benchmark:
    """One table: the script and arguments that write it, and how long that takes."""

    name: str
    script: str
    args: str
    minutes: int
    """About how long on this project's 2-core CPU (AVX-512), nothing else running."""
    tiny: str
    """The same script on a tiny setting (``--smoke``): the path works, the figures mean nothing."""
    quick: bool = False
    headline: str | None = None
    """The README's "How fast" row for it, until it has run (None: no README row)."""
    needs_cuda: bool = False
    needs_postgres: bool = False
    """Its script uses the PostgreSQL server of ``CARTPOLE_TEST_POSTGRES_URL`` (.ci/postgres.sh)."""
    env: tuple[tuple[str, str], ...] = ()
    """Environment variables the script runs under (e.g. ``cpu.AVX2_SETTINGS``), beside this process's."""

    def command(self, smoke: bool = False) -> list[str]:
        return [
            sys.executable,
            str(BENCHMARKS / self.script),
            *shlex.split(self.tiny if smoke else self.args),
        ]

    def shown(self) -> str:
        settings = [f"{name}={value}" for name, value in self.env]
        parts = [*settings, "python", f"benchmarks/{self.script}", self.args, "--table", self.name]
        return " ".join(part for part in parts if part)


AVX2 = tuple(AVX2_SETTINGS.items())
CPU_KINDS: tuple[tuple[str, tuple[tuple[str, str], ...]], ...] = (("", ()), ("-avx2", AVX2))
"""The profiling tables' two runs: as this CPU is, and as on an AVX2 CPU (emulated on an AVX-512 one)."""
TTS_AGENTS = "ppo,dqn,a2c,reinforce,cem"
ACROBOT_AGENTS = "ppo:acrobot,dqn,a2c:acrobot,reinforce:acrobot,cem,hill-climbing,random-search"
TUTORIALS = "dqn:tutorial-keras,dqn:tutorial-pytorch,random-search:tutorial"
TABLES = [
    Benchmark(
        "time-to-solve", "time_to_solve.py",
        f"--agents {TTS_AGENTS} --seeds 20 --first-seed 80000 --sb3 ppo,dqn,a2c --jobs 1", minutes=25,
        tiny=f"--agents {TTS_AGENTS} --seeds 1 --first-seed 80000 --sb3 ppo,dqn,a2c",
        headline="CPU seconds to a verified solve, beside Stable-Baselines3",
    ),
    Benchmark(
        "time-to-solve-avx2", "time_to_solve.py",
        f"--agents {TTS_AGENTS} --seeds 20 --first-seed 80000 --sb3 ppo,dqn,a2c --jobs 1", minutes=30,
        tiny=f"--agents {TTS_AGENTS} --seeds 1 --first-seed 80000 --sb3 ppo,dqn,a2c",
        headline="The same on an AVX2 CPU", env=AVX2,
    ),
    Benchmark(
        "population", "population.py",
        "--agent ppo,dqn --seeds 100 --first-seed 10100 --singles 0 --processes 10", minutes=8,
        tiny="--agent ppo,dqn --seeds 4 --first-seed 10100 --singles 0 --processes 1",
        headline="100 seeds in one process",
    ),
    Benchmark(
        "env-throughput", "env_throughput.py", "", minutes=2, quick=True,
        tiny="--sizes 1,4096 --seconds 0.1 --repeats 1 --no-compile-check",
        headline="Simulator: env steps per CPU second on one core",
    ),
    Benchmark(
        "env-throughput-avx2", "env_throughput.py", "", minutes=2, quick=True,
        tiny="--sizes 1,4096 --seconds 0.1 --repeats 1 --no-compile-check",
        env=AVX2,
    ),
    Benchmark(
        "tutorial-presets", "time_to_solve.py",
        f"--agents {TUTORIALS} --seeds 4 --first-seed 10200 --jobs 2", minutes=25,
        tiny=f"--agents {TUTORIALS} --seeds 1 --first-seed 10200 --max-seconds-per-run 20",
        headline="The tutorials' agents, faithfully",
    ),
    Benchmark(
        "acrobot", "time_to_solve.py",
        f"--env Acrobot-v1 --agents {ACROBOT_AGENTS} --seeds 5 --first-seed 10300 --jobs 1", minutes=15,
        tiny="--env Acrobot-v1 --agents ppo:acrobot,cem --seeds 1 --first-seed 10300 "
        "--max-seconds-per-run 10",
        headline="Acrobot-v1",
    ),
    Benchmark(
        "mountaincar", "time_to_solve.py",
        "--env MountainCar-v0 --agents ppo,dqn,a2c,reinforce,cem,hill-climbing,random-search --presets "
        "mountaincar --seeds 5 --first-seed 10400 --jobs 1", minutes=35,
        tiny="--env MountainCar-v0 --agents ppo,cem --presets mountaincar --seeds 1 --first-seed 10400 "
        "--max-seconds-per-run 10",
        headline="MountainCar-v0",
    ),
    Benchmark(
        "lunarlander", "time_to_solve.py",
        "--env LunarLander-v3 --agents ppo,dqn --presets lunarlander --seeds 5 --first-seed 10500 --sb3 ppo "
        "--jobs 2", minutes=60,
        tiny="--env LunarLander-v3 --agents ppo --presets lunarlander --seeds 1 --first-seed 10500 "
        "--max-seconds-per-run 10 "
        "--sb3 ppo --sb3-steps 20000",
        headline="LunarLander-v3",
    ),
    Benchmark(
        "crash-safety", "kill_resume.py", "", minutes=15,
        tiny="--agents cem,ppo-population --trials 2 --seed 1",
        headline="Crash safety: kill -9 at a random moment, then `--resume`",
    ),
    Benchmark(
        "claims", "claims.py", "--workers 1,64,256 --delay-ms 20 --join current,legacy --seconds 4",
        minutes=3, quick=True, tiny="--workers 1,2 --delay-ms 5 --join current,legacy --seconds 0.5",
        needs_postgres=True,
    ),
    Benchmark(
        "web-latency", "web_latency.py", "--sessions 1 20 --watch-load 4 --trainings 2", minutes=5,
        quick=True,
        tiny="--steps 100 --sessions 1 4 --episodes 3 --watch-load 1 --trainings 1",
        headline="Web app: play round-trip",
    ),
    Benchmark("web-start", "web_start.py", "--trials 5", minutes=2, quick=True, tiny="--trials 1 --warmup 0"),
    Benchmark(
        "pixels", "pixels.py", "--agents ppo:pixels --seeds 8 --first-seed 9900 --population", minutes=30,
        tiny="--agents ppo:pixels --seeds 1 --first-seed 9900 --budget 2k", headline="CartPole from pixels",
    ),
    Benchmark(
        "pixels-dqn", "pixels.py", "--agents dqn:pixels --seeds 10 --first-seed 9910", minutes=80,
        tiny="--agents dqn:pixels --seeds 1 --first-seed 9910 --budget 2k",
        headline="CartPole from pixels, DQN",
    ),
    Benchmark(
        "renderer", "renderer.py", "--sizes 30x100,40x60,60x200", minutes=2, quick=True,
        tiny="--sizes 30x100 --envs 1,64 --seconds 0.1 --repeats 1",
    ),
    *[
        Benchmark(
            f"phases{suffix}", "phases.py", "--seeds 3 --population 3", minutes=4, quick=True,
            tiny="--agents cem,ppo", env=env,
        )
        for suffix, env in CPU_KINDS
    ],
    *[
        Benchmark(
            f"kernels{suffix}", "kernels.py", "", minutes=2, quick=True, tiny="--seeds 10 --repeats 5",
            env=env,
        )
        for suffix, env in CPU_KINDS
    ],
    *[
        Benchmark(
            f"dqn-step{suffix}", "dqn_step.py", "table", minutes=4, quick=True,
            tiny="table --seeds 10 --steps 50 --warmup 80 --repeats 10 --trials 2", env=env,
        )
        for suffix, env in CPU_KINDS
    ],
    Benchmark(
        "gpu", "population.py", "--agent ppo,dqn --seeds 100 --first-seed 10100 --device cuda --singles 0 "
        "--processes 0", minutes=5, tiny="--agent ppo --seeds 4 --device cuda --singles 0 --processes 0",
        needs_cuda=True,
    ),
]  # fmt: skip
BY_NAME = {table.name: table for table in TABLES}
POSTGRES_URL = "CARTPOLE_TEST_POSTGRES_URL"


# ----------------------------------------------------------------------------------------------
# Running
# ----------------------------------------------------------------------------------------------


def missing_requirement(table: Benchmark) -> str | None:
    """Why ``table`` cannot run here (its script is not written yet, or it needs a GPU); None if it can."""
    if not (BENCHMARKS / table.script).is_file():
        return f"benchmarks/{table.script} is not here yet"
    if table.needs_postgres and not os.environ.get(POSTGRES_URL):
        return f"it needs a PostgreSQL server: source .ci/postgres.sh (it sets {POSTGRES_URL})"
    if table.needs_cuda:
        import torch

        if not torch.cuda.is_available():
            return "it needs a CUDA GPU"
    return None


def run_table(table: Benchmark, results_dir: Path, note: str, smoke: bool) -> bool:
    """Run ``table``'s script, which writes ``results_dir/NAME.md`` and ``.json``; True if it did."""
    command = [*table.command(smoke), "--table", table.name, "--results-dir", str(results_dir)]
    command += ["--note", note] if note else []
    print(f"== {table.name}: {' '.join(command[1:])}", flush=True)
    done = subprocess.run(command, cwd=tempfile.gettempdir(), env={**os.environ, **dict(table.env)})
    written = (results_dir / f"{table.name}.json").is_file()
    if done.returncode != 0:
        print(f"== {table.name}: the script exited {done.returncode}", file=sys.stderr)
    return done.returncode == 0 and written


# ----------------------------------------------------------------------------------------------
# The READMEs
# ----------------------------------------------------------------------------------------------


def read_record(results_dir: Path, name: str) -> dict[str, Any] | None:
    path = results_dir / f"{name}.json"
    return json.loads(path.read_text(encoding="utf-8")) if path.is_file() else None


def not_run_yet(table: Benchmark) -> str:
    where = " on a machine with a CUDA GPU" if table.needs_cuda else ""
    where += " after `source .ci/postgres.sh`" if table.needs_postgres else ""
    return f"*Not run yet:* `python benchmarks/run.py {table.name}`{where} (about {table.minutes} min).\n"


def with_tables(text: str, results_dir: Path) -> str:
    """``text`` (benchmarks/README.md) with each table block holding its current ``NAME.md``."""

    def table_text(match: re.Match[str]) -> str:
        name = match.group(2)
        path = results_dir / f"{name}.md"
        if path.is_file():
            body = path.read_text(encoding="utf-8")
        elif name in BY_NAME:
            body = not_run_yet(BY_NAME[name])
        else:
            raise SystemExit(f"benchmarks/README.md names a table {name!r} that run.py does not know")
        return match.group(1) + body + match.group(4)

    return TABLE_BLOCK.sub(table_text, text)


Row = dict[str, str]
"""A "How fast" row: measure, ours, peer, ratio, verified (machine and link are added)."""


def seconds(value: float | None) -> str:
    if value is None:
        return "never"
    return f"{value:.2f} s" if value < 1 else f"{value:.1f} s"


def fraction(found: dict[str, Any], solved: str = "final_solved") -> str:
    return f"{found[solved]}/{found['seeds']}"


AGENT_NAMES = {"ppo": "PPO", "dqn": "DQN", "a2c": "A2C", "reinforce": "REINFORCE", "cem": "CEM"}


Group = dict[str, Any]


def agents_and_peers(
    summary: dict[str, Any],
) -> tuple[list[tuple[str, Group, Group]], list[tuple[str, Group]]]:
    """A time-to-solve table's groups of our agents: (name, ours, SB3's) for those SB3 has a peer
    for, then (name, ours) for the others, in :data:`AGENT_NAMES`' order."""
    groups = {group["agent"]: group for group in summary["groups"]}
    ours = [(name, groups[agent], groups.get(f"sb3-{agent}")) for agent, name in AGENT_NAMES.items()
            if agent in groups]  # fmt: skip
    paired = [(name, found, peer) for name, found, peer in ours if peer is not None]
    return paired, [(name, found) for name, found, peer in ours if peer is None]


def time_to_solve_rows(summary: dict[str, Any]) -> list[Row]:
    """Our agents beside SB3's in the same run: median CPU seconds to a verified solve, a row each;
    the agents SB3 has no peer for share one row."""
    paired, alone = agents_and_peers(summary)
    rows = []
    for name, found, peer in paired:
        ratio = "-"
        if found["median_cpu"] and peer["median_cpu"]:
            ratio = f"{peer['median_cpu'] / found['median_cpu']:.1f}x less CPU"
        rows.append({
            "measure": f"{name}: CPU seconds to a verified solve, median of {found['seeds']} unseen seeds",
            "ours": seconds(found["median_cpu"]),
            "peer": f"SB3 (RL Zoo) {seconds(peer['median_cpu'])}",
            "ratio": ratio,
            "verified": f"{fraction(found)} (SB3 {fraction(peer)})",
        })  # fmt: skip
    if alone:
        seeds = ", ".join(sorted({str(found["seeds"]) for _, found in alone}))
        rows.append({
            "measure": f"{', '.join(n for n, _ in alone)}: the same, median of {seeds} unseen seeds",
            "ours": ", ".join(seconds(found["median_cpu"]) for _, found in alone),
            "peer": "-",
            "ratio": "-",
            "verified": ", ".join(fraction(found) for _, found in alone),
        })  # fmt: skip
    return rows


def time_to_solve_one_row(measure: str) -> Callable[[dict[str, Any]], list[Row]]:
    """:func:`time_to_solve_rows` folded into one row named ``measure`` (another CPU's run of the same
    table): the agents with an SB3 peer, then the others, each cell a list in that order."""

    def rows(summary: dict[str, Any]) -> list[Row]:
        return [one_row(measure, summary)] if summary["groups"] else []

    return rows


def one_row(measure: str, summary: dict[str, Any]) -> Row:
    """The row of :func:`time_to_solve_one_row`."""
    paired, alone = agents_and_peers(summary)
    names = ", ".join(name for name, _, _ in paired) + ("; " if paired and alone else "")
    names += ", ".join(name for name, _ in alone)
    seeds = ", ".join(
        sorted({str(g["seeds"]) for g in summary["groups"] if not g["agent"].startswith("sb3-")})
    )

    def listed(values: list[str]) -> str:
        return ", ".join(values) if values else "-"

    ratios = [
        f"{peer['median_cpu'] / found['median_cpu']:.1f}x"
        if found["median_cpu"] and peer["median_cpu"]
        else "-"
        for _, found, peer in paired
    ]
    solved = listed([fraction(found) for _, found, _ in paired])
    if alone:
        solved += "; " + listed([fraction(found) for _, found in alone])
    return {
        "measure": f"{measure} ({names}): CPU seconds, median of {seeds} unseen seeds",
        "ours": listed([seconds(found["median_cpu"]) for _, found, _ in paired])
        + ("; " + listed([seconds(found["median_cpu"]) for _, found in alone]) if alone else ""),
        "peer": "SB3 (RL Zoo) " + listed([seconds(peer["median_cpu"]) for _, _, peer in paired]),
        "ratio": listed(ratios) + " less CPU",
        "verified": f"{solved} (SB3 {listed([fraction(peer) for _, _, peer in paired])})",
    }  # fmt: skip


def population_rows(summary: dict[str, Any]) -> list[Row]:
    """A population's wall time and peak memory; its CPU per seed against separate processes'."""
    rows = []
    for found in summary["agents"]:
        name = AGENT_NAMES.get(found["agent"], found["agent"])
        row = {
            "measure": f"{found['seeds']} {name} seeds in one process, to the last verdict",
            "ours": f"{found['wall']:.1f} s wall, {found['rss_mb']:,.0f} MB peak",
            "peer": "-",
            "ratio": "-",
            "verified": f"{found['verified']}/{found['seeds']}",
        }
        if "process_cpu" in found:
            row["peer"] = f"a `cartpole train` process per seed: {found['process_cpu']:.1f} CPU s each"
            row["ratio"] = f"{found['process_cpu'] / found['cpu_per_seed']:.1f}x less CPU per seed"
        rows.append(row)
    return rows


def env_throughput_rows(summary: dict[str, Any]) -> list[Row]:
    """Our simulator against Gymnasium's vector env at the largest size measured: float64 first, the
    dtype ``gym.make_vec("cartpole/CartPole-v1", ...)`` gives by default, then float32 (``dtype=``)."""
    sizes = [key for key in summary["steps_per_s"] if key.isdigit()]
    if not sizes:
        return []
    n = max(sizes, key=int)
    rates = summary["steps_per_s"][n]
    kinds = (("fast float64", "float64 (the default)"), ("fast float32", "float32 (`dtype=np.float32`)"))
    return [
        {
            "measure": f"Simulator, {name}: env steps per CPU second, {int(n):,} envs on one core",
            "ours": rate(rates[kind]),
            "peer": f"Gymnasium's vector env {rate(rates['gymnasium'])}",
            "ratio": f"{rates[kind] / rates['gymnasium']:.1f}x",
            "verified": "-",
        }
        for kind, name in kinds
        if kind in rates
    ]


def label(group: dict[str, Any]) -> str:
    """``agent:preset`` for a tutorial's preset, the agent alone for the others (each env's own)."""
    return f"{group['agent']}:{group['preset']}" if group["preset"].startswith("tutorial") else group["agent"]


def rate(value: float) -> str:
    """``2.3e8``: two digits and a power of ten."""
    mantissa, _, exponent = f"{value:.1e}".partition("e")
    return f"{mantissa}e{int(exponent)}"


def solve_rate_rows(measure: str) -> Callable[[dict[str, Any]], list[Row]]:
    """One row of verified solves per agent and preset (the tutorials', another env's)."""

    def rows(summary: dict[str, Any]) -> list[Row]:
        groups = summary["groups"]
        seeds = {group["seeds"] for group in groups}
        each = ", ".join(f"{label(group)} {fraction(group)}" for group in groups)
        solved, total = sum(g["final_solved"] for g in groups), sum(g["seeds"] for g in groups)
        of = f"{seeds.pop()} unseen seeds each" if len(seeds) == 1 else "unseen seeds"
        return [{"measure": f"{measure}: verified, {of}", "ours": each, "peer": "-", "ratio": "-",
                 "verified": f"{solved}/{total}"}]  # fmt: skip

    return rows


def crash_safety_rows(summary: dict[str, Any]) -> list[Row]:
    return [
        {
            "measure": f"Crash safety: {summary['trials']} kill -9s at random moments, then `--resume`",
            "ours": f"largest loss {summary['largest_loss']:,} env steps (a checkpoint interval: "
            f"{summary['largest_loss_interval']:,.0f})",
            "peer": "-",
            "ratio": "-",
            "verified": f"{summary['resumed']}/{summary['trials']} resumed to a verdict",
        }
    ]


def web_latency_rows(summary: dict[str, Any]) -> list[Row]:
    """The play round-trip with watchers as the Watch page asks (the target's case), else with the
    most sessions measured."""
    plays = [row for row in summary["rows"] if row["measure"].startswith("play")]
    if not plays:
        return []
    watched = [row for row in plays if row["measure"].endswith("watching")]
    worst = watched[-1] if watched else plays[-1]
    target = f" (target {worst['target_ms']:g} ms)" if worst.get("target_ms") else ""
    return [
        {
            "measure": f"Web app: {worst['measure']}, p99",
            "ours": f"{worst['p99_ms']:.1f} ms{target}",
            "peer": "-",
            "ratio": "-",
            "verified": "-",
        }
    ]


README_ROWS: dict[str, Callable[[dict[str, Any]], list[Row]]] = {
    "time-to-solve": time_to_solve_rows,
    "time-to-solve-avx2": time_to_solve_one_row("The same as on an AVX2 CPU"),
    "population": population_rows,
    "env-throughput": env_throughput_rows,
    "tutorial-presets": solve_rate_rows("The tutorials' agents within their own budgets"),
    "acrobot": solve_rate_rows("Acrobot-v1, each agent's preset"),
    "mountaincar": solve_rate_rows("MountainCar-v0, each agent's `mountaincar` preset"),
    "lunarlander": lambda summary: [
        row | {"measure": f"LunarLander-v3, {row['measure']}"} for row in time_to_solve_rows(summary)
    ],
    "crash-safety": crash_safety_rows,
    "web-latency": web_latency_rows,
}


def how_fast(results_dir: Path) -> str:
    """The README's "How fast" table: a row per measure, from each table's summary."""
    lines = [
        "| measure | ours | peer, same run | ratio | verified | machine | table |",
        "|---|---|---|---|---|---|---|",
    ]
    for table in TABLES:
        if table.headline is None:
            continue
        link = f"[{table.name}](benchmarks/README.md#{table.name})"
        record = read_record(results_dir, table.name)
        if record is None:
            cells = [
                table.headline,
                f"not run yet: `python benchmarks/run.py {table.name}`",
                "-",
                "-",
                "-",
                "-",
            ]
            lines.append("| " + " | ".join([*cells, link]) + " |")
            continue
        machine = describe_machine(record["machine"]) + (f"; {record['note']}" if record.get("note") else "")
        builder = README_ROWS.get(table.name)
        rows = builder(record["summary"]) if builder else record["summary"].get("readme", [])
        for row in rows:
            cells = [row["measure"], row["ours"], row["peer"], row["ratio"], row["verified"], machine, link]
            lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def with_how_fast(text: str, results_dir: Path) -> str:
    if not HOW_FAST_BLOCK.search(text):
        raise SystemExit("README.md has no <!-- how-fast --> ... <!-- end how-fast --> block")
    return HOW_FAST_BLOCK.sub(lambda m: m.group(1) + how_fast(results_dir) + m.group(3), text)


def assembled(results_dir: Path) -> dict[Path, str]:
    """benchmarks/README.md and README.md as ``results_dir``'s tables make them."""
    return {
        BENCHMARKS_README: with_tables(BENCHMARKS_README.read_text(encoding="utf-8"), results_dir),
        README: with_how_fast(README.read_text(encoding="utf-8"), results_dir),
    }


# ----------------------------------------------------------------------------------------------
# Driver
# ----------------------------------------------------------------------------------------------


def chosen_tables(parser: argparse.ArgumentParser, args: argparse.Namespace) -> list[Benchmark]:
    unknown = [name for name in args.tables if name not in BY_NAME]
    if unknown:
        parser.error(f"no table {', '.join(unknown)}; --list shows them: {', '.join(BY_NAME)}")
    if args.all:
        return TABLES
    if args.quick:
        return [t for t in TABLES if t.quick] + [BY_NAME[n] for n in args.tables if not BY_NAME[n].quick]
    return [BY_NAME[name] for name in args.tables]


def print_list() -> None:
    for table in TABLES:
        kind = "quick" if table.quick else "long"
        print(f"{table.name:<17} {kind:<5} about {table.minutes:>2} min   {table.shown()}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("tables", nargs="*", metavar="TABLE", help="tables to re-run (--list names them)")
    parser.add_argument("--quick", action="store_true", help="the tables that take minutes")
    parser.add_argument("--all", action="store_true", help="every table")
    parser.add_argument("--list", action="store_true", help="every table, its command and duration")
    parser.add_argument("--assemble", action="store_true", help="only rewrite the READMEs from the results")
    parser.add_argument(
        "--check", action="store_true", help="exit 1 if a README is not what the results make"
    )
    parser.add_argument("--smoke", action="store_true", help="tiny settings, into a temporary folder")
    parser.add_argument("--note", default="", help="said on each table's machine line")
    parser.add_argument("--results-dir", default=None, help="where tables are written and read")
    args = parser.parse_args(argv)
    if args.list:
        print_list()
        return 0
    default_dir = Path(tempfile.mkdtemp(prefix="cartpole-bench-smoke-")) if args.smoke else RESULTS_DIR
    results_dir = Path(args.results_dir) if args.results_dir else default_dir
    if args.check:
        stale = [
            path for path, text in assembled(results_dir).items() if path.read_text(encoding="utf-8") != text
        ]
        for path in stale:
            print(
                f"{path.relative_to(ROOT)} differs from what the tables make: run.py --assemble rewrites it"
            )
        return 1 if stale else 0
    tables = [] if args.assemble else chosen_tables(parser, args)
    if not tables and not args.assemble:
        parser.error("name tables, or --quick, --all, --assemble, --check or --list")
    failed = []
    for table in tables:
        reason = missing_requirement(table)
        if reason is not None:
            print(f"== {table.name}: skipped, {reason}", file=sys.stderr)
            if table.name in args.tables:
                failed.append(table.name)
            continue
        if not run_table(table, results_dir, args.note, args.smoke):
            failed.append(table.name)
    into_repository = results_dir.resolve() == RESULTS_DIR.resolve()
    for path, text in assembled(results_dir).items():
        # The repository's READMEs come from benchmarks/results/ only; other tables' beside them.
        target = path if into_repository else results_dir / str(path.relative_to(ROOT)).replace("/", "-")
        target.write_text(text, encoding="utf-8")
        print(f"wrote {target}")
    if failed:
        print(f"failed or skipped: {', '.join(failed)}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
