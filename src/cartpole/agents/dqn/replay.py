"""The replay memories of S seeds as one: :class:`StackedReplay`, S ring buffers in one table, and the
minibatches of a training round drawn from them for every seed at once.

Each row of the ``[S, capacity, 2 * obs_dim + 3]`` table is laid out as obs | next_obs | action |
reward | terminated; each seed has its own write position and fill count. The minibatches of a
training round's gradient steps, every seed's, come in one ``index_select``. Image observations are
kept apart, as uint8 frames each stored once (:class:`~cartpole.agents.dqn.frames.StackedFrames`:
a row's two frame stacks share all but a frame or two with its neighbours' rows), beside a
``[S, capacity, 3]`` table of action | reward | terminated. With n-step returns a row's reward is
the n steps' discounted sum and its next obs the one n steps on (:mod:`cartpole.agents.dqn.n_step`
makes such rows).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
import torch

from cartpole.agents.dqn.config import DQNConfig
from cartpole.agents.dqn.frames import StackedFrames, frame_store_bytes
from cartpole.agents.nn.flat_parameters import to_device
from cartpole.core.errors import ConfigError
from cartpole.envs import EnvInfo


class Minibatch(NamedTuple):
    """One gradient step's transitions of every seed: observations and next observations [S, B,
    obs_dim] (image networks: uint8 [S, B, C, H, W]), actions [S, B, 1] (int64), rewards and
    terminated flags [S, B]."""

    observations: torch.Tensor
    next_observations: torch.Tensor
    actions: torch.Tensor
    rewards: torch.Tensor
    terminated: torch.Tensor


class StackedReplay:
    """S ring buffers of transitions in one ``[S, capacity, 2 * obs_dim + 3]`` table, each row laid
    out as obs | next_obs | action | reward | terminated; each seed has its own write position and
    fill count.

    Image observations (``obs_shape`` [stack, H, W]) stay uint8 in their own store, ``frames`` (each
    frame once, for ``num_envs`` envs a seed and rows of ``n_step`` steps), and the table's rows hold
    only action | reward | terminated (``obs_dim`` is then 0: no observation floats in a row)."""

    def __init__(
        self,
        seeds: int,
        capacity: int,
        obs_shape: int | tuple[int, ...],
        device: torch.device,
        num_envs: int = 1,
        n_step: int = 1,
    ):
        shape = (obs_shape,) if isinstance(obs_shape, int) else tuple(obs_shape)
        self.capacity = capacity
        self.obs_dim = shape[0] if len(shape) == 1 else 0
        """Observation floats in a table row (0 for images, which live in ``images``)."""
        # Uninitialized, not zeros: ``torch.zeros`` writes every page of the table at once, so a
        # population's whole capacity would be resident from the start; here a page costs memory when
        # it is first written. No row at or past a seed's fill count is ever read (minibatches draw
        # below it), except row 0, the padding slot of a seed with no rows yet: zeroed.
        self.table = torch.empty(seeds, capacity, 2 * self.obs_dim + 3, device=device)
        self.table[:, 0] = 0.0
        self.frames: StackedFrames | None = None
        """Image observations' frames, each once (None: flat observations)."""
        if len(shape) == 3:
            self.frames = StackedFrames(seeds, capacity, shape, num_envs, n_step, device)
        self.pos = np.zeros(seeds, dtype=np.int64)
        self.size = np.zeros(seeds, dtype=np.int64)
        self.host_view()

    @property
    def nbytes(self) -> int:
        """Bytes of the stores (allocated; a page is resident once written)."""
        frames = 0 if self.frames is None else self.frames.nbytes
        return self.table.nbytes + frames

    def host_view(self) -> None:
        """On the CPU rows are written through a numpy view of the table (cheaper for a few rows)."""
        self.host = self.table.numpy() if self.table.device.type == "cpu" else None

    def add(self, valid: np.ndarray, fields: list[np.ndarray]) -> None:
        """Append the transitions of the envs where ``valid`` [S, N] is True to their seeds' buffers,
        in env order, overwriting the oldest rows when full. ``fields`` are obs [S * N, obs_dim],
        actions, rewards, next obs and terminated (each [S * N])."""
        d = self.obs_dim
        counts = valid.sum(axis=1)
        offsets = np.cumsum(valid, axis=1) - 1
        # A seed with more new rows than capacity keeps its newest `capacity` (a ring buffer's overwrite).
        kept = valid & (offsets >= (counts - self.capacity)[:, None])
        seed_rows, env_columns = np.nonzero(kept)
        if len(seed_rows):
            slots = (self.pos[seed_rows] + offsets[seed_rows, env_columns]) % self.capacity
            envs = seed_rows * valid.shape[1] + env_columns
            observations, actions, rewards, next_observations, terminated = fields
            rows = np.empty((len(envs), 2 * d + 3), dtype=np.float32)
            if self.frames is None:
                rows[:, :d] = observations[envs]
                rows[:, d : 2 * d] = next_observations[envs]
            rows[:, 2 * d] = actions[envs]
            rows[:, 2 * d + 1] = rewards[envs]
            rows[:, 2 * d + 2] = terminated[envs]
            if self.host is not None:
                self.host[seed_rows, slots] = rows
            else:
                device = self.table.device
                index = (
                    to_device(torch.from_numpy(seed_rows), device),
                    to_device(torch.from_numpy(slots), device),
                )
                self.table[index] = to_device(torch.from_numpy(rows), device)
            if self.frames is not None:
                live = np.minimum(self.size + counts, self.capacity)
                self.frames.write(
                    seed_rows, slots, env_columns, observations[envs], next_observations[envs], live
                )
        self.pos = (self.pos + counts) % self.capacity
        self.size = np.minimum(self.size + counts, self.capacity)

    def gather_images(self, index: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The uint8 observations and next observations [S, B, C, H, W] of the rows ``index`` [S, B]."""
        assert self.frames is not None
        return self.frames.gather(index)

    def gather(self, index: torch.Tensor) -> torch.Tensor:
        """The rows ``index`` [S, B] (slot numbers within each seed's buffer): [S, B, 2 * obs_dim + 3]."""
        seeds, capacity = self.table.shape[:2]
        base = torch.arange(seeds, device=index.device).unsqueeze(1) * capacity
        flat = self.table.view(seeds * capacity, -1).index_select(0, (index + base).view(-1))
        return flat.view(seeds, index.shape[1], -1)

    def keep(self, rows_np: np.ndarray) -> None:
        """Keep only the seeds at ``rows_np`` (rising), moving each one's filled rows down in place.

        Not ``table[rows]``: that copy would make every page of a new ``[S, capacity, ...]`` table
        resident at once (the table's unwritten pages cost nothing until then), doubling the replay's
        memory at the moment a seed stops. Rows past a seed's fill count are never read."""
        for new, old in enumerate(rows_np.tolist()):
            if new != old:
                filled = int(self.size[old])
                self.table[new, :filled] = self.table[old, :filled]
        self.table = self.table[: len(rows_np)]
        if self.frames is not None:
            self.frames.keep(rows_np)
        self.pos, self.size = self.pos[rows_np], self.size[rows_np]
        self.host_view()

    def row_state(self, row: int) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
        """Seed ``row``'s buffer: the rows it holds, oldest first, and its write position."""
        d, size = self.obs_dim, int(self.size[row])
        written = self.table[row, :size].to("cpu", copy=True)
        tensors = {
            "observations": written[:, :d].clone(),
            "actions": written[:, 2 * d].long(),
            "rewards": written[:, 2 * d + 1].clone(),
            "next_observations": written[:, d : 2 * d].clone(),
            "terminated": written[:, 2 * d + 2].clone(),
        }
        data = {"capacity": self.capacity, "pos": int(self.pos[row]), "size": size}
        if self.frames is not None:  # uint8 frames, each once, and each row's frames' serials
            del tensors["observations"], tensors["next_observations"]
            frames, frame_data = self.frames.row_state(row, size)
            tensors |= frames
            data |= frame_data
        return tensors, data

    def load_row_state(self, row: int, tensors: dict[str, torch.Tensor], data: dict[str, Any]) -> None:
        if int(data["capacity"]) != self.capacity:
            raise ConfigError(f"replay capacity {data['capacity']} in the checkpoint, {self.capacity} here")
        d, size = self.obs_dim, int(data["size"])
        rows = torch.zeros(self.capacity, 2 * d + 3, device="cpu")
        if self.frames is not None:
            if "frames" not in tensors:
                raise ConfigError(
                    "its replay holds frame stacks, saved before the replay kept each frame once: "
                    "it cannot be resumed; train again with --from-scratch"
                )
            self.frames.load_row_state(row, tensors, data)
        else:
            rows[:size, :d] = tensors["observations"]
            rows[:size, d : 2 * d] = tensors["next_observations"]
        rows[:size, 2 * d] = tensors["actions"].to(torch.float32)
        rows[:size, 2 * d + 1] = tensors["rewards"]
        rows[:size, 2 * d + 2] = tensors["terminated"]
        self.table[row] = rows.to(self.table.device)  # in place: the host view stays valid
        self.pos[row], self.size[row] = int(data["pos"]), size

    def sample_slots(
        self,
        training: np.ndarray,
        counts: np.ndarray,
        steps: int,
        rows: int,
        generators: list[torch.Generator],
    ) -> torch.Tensor:
        """Each training seed's minibatch rows (``counts`` of ``rows``) for ``steps`` gradient steps,
        drawn uniformly (with replacement) from the rows its buffer holds, from its own generator of
        ``generators``; [S, steps, rows] (padding: slot 0)."""
        slots = torch.zeros(len(self.size), steps, rows, dtype=torch.int64, device="cpu")
        for row in np.flatnonzero(training):
            size, count = int(self.size[row]), int(counts[row])
            generator = generators[row]
            slots[row, :, :count] = torch.randint(0, size, (steps, count), generator=generator, device="cpu")
        return to_device(slots, self.table.device)

    def minibatches(self, slots: torch.Tensor) -> list[Minibatch]:
        """Every gradient step's :class:`Minibatch` of a round, from its rows ``slots`` [S, steps, B].
        The buffers do not change within a round, so the rows of all its steps come in one
        ``index_select`` and each field is laid out [steps, S, B, ...] in one copy; image networks'
        pixels are gathered a step at a time."""
        seeds, steps, rows = slots.shape
        d = self.obs_dim
        table = self.gather(slots.view(seeds, steps * rows))
        table = table.view(seeds, steps, rows, -1).transpose(0, 1)  # [steps, S, B, row width]
        actions = table[..., 2 * d].long().unsqueeze(3)
        rewards, terminated = table[..., 2 * d + 1].contiguous(), table[..., 2 * d + 2].contiguous()
        if self.frames is None:
            observations = table[..., :d].contiguous()
            next_observations = table[..., d : 2 * d].contiguous()
            pixels = list(zip(observations, next_observations, strict=True))
        else:
            pixels = [self.gather_images(slots[:, step]) for step in range(steps)]
        return [
            Minibatch(obs, next_obs, actions[step], rewards[step], terminated[step])
            for step, (obs, next_obs) in enumerate(pixels)
        ]


def replay_bytes(config: DQNConfig, env: EnvInfo) -> int:
    """The bytes of one seed's replay memory: float32 rows, or for images uint8 frames each stored once
    beside a float32 action | reward | terminated."""
    if env.is_image:
        frames = frame_store_bytes(config.buffer_size, env.obs_shape, config.num_envs, config.n_step)
        return frames + config.buffer_size * 3 * 4
    return config.buffer_size * (2 * env.obs_dim + 3) * 4


__all__ = ["Minibatch", "StackedReplay", "replay_bytes"]
