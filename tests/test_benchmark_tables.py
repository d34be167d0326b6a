"""``benchmarks/run.py``: a script writes its table and raw results, and the two READMEs are made from
the tables (benchmarks/README.md's table blocks, the README's "How fast"), so neither can drift."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).parents[1]
RUN = ROOT / "benchmarks" / "run.py"


def run(*args: str, timeout: float = 300) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, str(RUN), *args], capture_output=True, text=True, timeout=timeout)


def how_fast(readme: str) -> str:
    found = re.search(r"<!-- how-fast[^\n]*-->\n(.*?)<!-- end how-fast -->", readme, re.S)
    assert found, "no how-fast block"
    return found.group(1)


def test_the_readmes_hold_what_the_benchmark_tables_make():
    done = run("--check")
    assert done.returncode == 0, done.stdout + done.stderr


def test_a_script_writes_its_table_and_run_py_copies_it_into_the_benchmarks_readme(tmp_path):
    done = run("kernels", "--smoke", "--results-dir", str(tmp_path), "--note", "a test")
    assert done.returncode == 0, done.stdout + done.stderr
    table = (tmp_path / "kernels.md").read_text()
    first = table.splitlines()[0]
    assert first.startswith("`python benchmarks/kernels.py --seeds 10 --repeats 5 --table kernels`")
    assert "CPUs" in first and "AVX-512" in first and "**a test**" in first and "--note" not in first
    record = json.loads((tmp_path / "kernels.json").read_text())
    assert record["command"] in first and record["machine"]["cpus"] >= 1 and record["rows"]
    readme = (tmp_path / "benchmarks-README.md").read_text()
    assert "<!-- table: kernels -->\n" + table + "<!-- end table: kernels -->" in readme
    assert "*Not run yet:* `python benchmarks/run.py time-to-solve`" in readme
    assert (ROOT / "benchmarks" / "README.md").read_text() != readme  # the repository's is untouched


def test_how_fast_puts_ours_beside_the_peer_of_the_same_run(tmp_path):
    groups = [
        {"agent": "ppo", "preset": "default", "seeds": 20, "final_solved": 19, "median_cpu": 0.5},
        {"agent": "sb3-ppo", "preset": "rl-zoo", "seeds": 20, "final_solved": 20, "median_cpu": 3.5},
        {"agent": "dqn", "preset": "default", "seeds": 20, "final_solved": 2, "median_cpu": None},
    ]
    record = {
        "command": "python benchmarks/time_to_solve.py",
        "machine": {"cpu": "Some CPU", "avx512": False, "cpus": 2},
        "note": "",
        "summary": {"env": "CartPole-v1", "groups": groups},
    }
    (tmp_path / "time-to-solve.json").write_text(json.dumps(record))
    done = run("--assemble", "--results-dir", str(tmp_path))
    assert done.returncode == 0, done.stdout + done.stderr
    table = how_fast((tmp_path / "README.md").read_text())
    ppo = next(line for line in table.splitlines() if line.startswith("| PPO"))
    cells = [cell.strip() for cell in ppo.strip("|").split("|")]
    assert cells[1:6] == ["0.50 s", "SB3 (RL Zoo) 3.5 s", "7.0x less CPU", "19/20 (SB3 20/20)",
                          "Some CPU, no AVX-512, 2 CPUs"]  # fmt: skip
    assert "(benchmarks/README.md#time-to-solve)" in cells[6]
    assert "| DQN: the same, median of 20 unseen seeds | never | - | - | 2/20 |" in table
    assert "not run yet: `python benchmarks/run.py population`" in table


AVX2_SETTINGS = {
    "NUMBA_CPU_NAME": "haswell",
    "ATEN_CPU_CAPABILITY": "avx2",
    "MKL_CBWR": "AVX2",
    "NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512_ICL AVX512_SPR",
}


def machine_under(env: dict[str, str]) -> dict:
    """``benchmarks/cpu.py``'s machine record in a process with ``env`` added to (or, for the AVX2
    settings it leaves out, removed from) this one's environment."""
    base = {k: v for k, v in os.environ.items() if k not in AVX2_SETTINGS}
    path = str(ROOT / "benchmarks")
    code = f"import json, sys; sys.path.insert(0, {path!r}); import cpu; print(json.dumps(cpu.machine()))"
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env={**base, **env}, check=True
    )
    return json.loads(done.stdout)


def test_a_table_made_under_the_avx2_settings_on_an_avx512_cpu_says_emulated_avx2():
    plain = machine_under({})
    assert plain["emulated"] is None and plain["float_paths"] == {}
    emulated = machine_under(AVX2_SETTINGS)
    assert emulated["float_paths"] == AVX2_SETTINGS
    assert emulated["emulated"] == ("AVX2" if emulated["avx512"] else None)  # an AVX2 CPU emulates nothing
    assert emulated["numpy_simd"] != "X86_V4"  # NumPy's own loops too, not only numba's, torch's, MKL's
    partly = machine_under({"ATEN_CPU_CAPABILITY": "avx2"})  # torch's kernels alone: not an AVX2 CPU
    assert partly["emulated"] is None and partly["float_paths"] == {"ATEN_CPU_CAPABILITY": "avx2"}
    without_numpy = machine_under({k: v for k, v in AVX2_SETTINGS.items() if k != "NPY_DISABLE_CPU_FEATURES"})
    assert without_numpy["emulated"] is None  # NumPy's loops left on AVX-512: not called emulated AVX2
    assert without_numpy["numpy_simd"] == ("X86_V4" if plain["avx512"] else plain["numpy_simd"])


def test_the_machine_line_of_an_emulated_avx2_table_says_so(tmp_path):
    groups = [{"agent": "ppo", "preset": "default", "seeds": 20, "final_solved": 20, "median_cpu": 0.5}]
    record = {
        "command": "python benchmarks/time_to_solve.py",
        "machine": {"cpu": "Some CPU", "avx512": True, "emulated": "AVX2", "cpus": 2},
        "note": "",
        "summary": {"env": "CartPole-v1", "groups": groups},
    }
    (tmp_path / "time-to-solve.json").write_text(json.dumps(record))
    done = run("--assemble", "--results-dir", str(tmp_path))
    assert done.returncode == 0, done.stdout + done.stderr
    said = "Some CPU, emulated AVX2 on AVX-512 (numba, torch and MKL kernels; NumPy's own on AVX-512), 2 CPUs"
    assert said in how_fast((tmp_path / "README.md").read_text())  # a table from before NumPy's was set
    record["machine"]["numpy_simd"] = "X86_V3"
    (tmp_path / "time-to-solve.json").write_text(json.dumps(record))
    assert run("--assemble", "--results-dir", str(tmp_path)).returncode == 0
    said = "Some CPU, emulated AVX2 on AVX-512 (numba, torch, MKL and NumPy kernels), 2 CPUs"
    assert said in how_fast((tmp_path / "README.md").read_text())


def test_the_simulator_rows_name_the_dtype_and_show_the_default_float64_first(tmp_path):
    rates = {"gymnasium": 1e7, "fast float32": 2e8, "fast float64": 5e7}
    record = {
        "command": "python benchmarks/env_throughput.py",
        "machine": {"cpu": "Some CPU", "avx512": False, "cpus": 2},
        "note": "",
        "summary": {"steps_per_s": {"16": rates, "65536": rates, "single": rates}},
    }
    (tmp_path / "env-throughput.json").write_text(json.dumps(record))
    done = run("--assemble", "--results-dir", str(tmp_path))
    assert done.returncode == 0, done.stdout + done.stderr
    rows = [
        line for line in how_fast((tmp_path / "README.md").read_text()).splitlines() if "Simulator" in line
    ]
    assert [row.split("|")[1].strip() for row in rows] == [
        "Simulator, float64 (the default): env steps per CPU second, 65,536 envs on one core",
        "Simulator, float32 (`dtype=np.float32`): env steps per CPU second, 65,536 envs on one core",
    ]
    assert "| 5.0e7 |" in rows[0] and "| 5.0x |" in rows[0] and "| 20.0x |" in rows[1]
