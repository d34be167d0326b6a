"""Seeds: training seeds live below 2**32, evaluation seeds in [2**32, 2**33).

Keeping the two ranges apart means an evaluation never replays a start state that training saw.
"""

from __future__ import annotations

import random

import numpy as np

EVAL_SEED_LOW = 2**32
EVAL_SEED_SPAN = 2**32
MAX_TRAIN_SEED = 2**32 - 1


def eval_seed(run_seed: int, index: int) -> int:
    """Base seed of the ``index``-th evaluation of a run: deterministic, disjoint from training."""
    word = np.random.SeedSequence([run_seed, index, 0xE7A1]).generate_state(1, dtype=np.uint64)[0]
    return EVAL_SEED_LOW + int(word) % (EVAL_SEED_SPAN - 10**6)


FINAL_EVAL_INDEX = 2**31
"""Index of a run's final verdict in ``eval_seed``: no in-training evaluation reaches it."""


def final_eval_seed(run_seed: int) -> int:
    """Base seed of a run's final verdict: never used in training or in-training evaluations."""
    return eval_seed(run_seed, FINAL_EVAL_INDEX)


def fresh_eval_seed() -> int:
    """A seed from OS entropy in the evaluation range, for verdicts on never-seen episodes."""
    return EVAL_SEED_LOW + random.SystemRandom().randrange(EVAL_SEED_SPAN - 10**6)


def derived_seed(seed: int, stream: str) -> int:
    """A 64-bit seed for one named random stream of a run (``"init"``, ``"replay"``, ...), independent
    of the run seed's other uses."""
    words = np.random.SeedSequence([seed, *stream.encode()]).generate_state(2, dtype=np.uint32)
    return int(words[0]) << 32 | int(words[1])


def describe_seeds(seeds: list[int]) -> str:
    """``seeds`` as ``--seeds`` names them, runs of consecutive seeds as ranges: ``0-9,20``."""
    parts: list[str] = []
    ordered = sorted(seeds)
    start = 0
    for i, seed in enumerate(ordered):
        if i + 1 == len(ordered) or ordered[i + 1] != seed + 1:
            low = ordered[start]
            parts.append(str(low) if low == seed else f"{low}-{seed}")
            start = i + 1
    return ",".join(parts)
