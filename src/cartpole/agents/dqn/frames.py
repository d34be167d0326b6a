"""The pixels of S seeds' replay memories with each frame stored once: :class:`StackedFrames`.

A replay row of a pixel env holds two frame stacks (obs and next obs, ``stack`` frames each), but
consecutive observations of an env share all frames but one, and an n-step row's next obs shares
frames with the rows after it. Stored as stacks, a frame sits in the replay about ``2 * stack``
times; here each distinct frame is stored once, in a per-seed ring of frames ``[S, F, H, W]``, and a
row keeps the serial numbers of its frames (``[2, S, capacity, stack]``, obs then next obs). A new
row's frames are looked up among the last frames stored for the same env (identical pixels: the
same frame), and only those not found are stored. The stacks read back are the stacks written, bit
for bit (tested); only the memory differs: about one frame a row instead of ``2 * stack``.

As Stable-Baselines3's ``optimize_memory_usage`` stores each observation once instead of twice, here
each frame once instead of ``2 * stack`` times. A row's frames are found by content, so episode
starts, autoresets, n-step rows and resumed runs need no bookkeeping of which frame came from where:
a frame not found is stored again, which costs memory, never correctness.

Serial numbers grow per seed; frame ``serial`` lives in slot ``serial % F``. A row adds one new frame
(its next obs' newest) and an episode one more (its first frame, which fills the first stack), so
``F`` = 1.5 rows a frame holds episodes down to 3 steps; CartPole's shortest take 8. A write that
overwrote a frame a live row still uses would raise instead of corrupting that row.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import torch

from cartpole.agents.nn.flat_parameters import to_device

OBS, NEXT = 0, 1


def frame_capacity(capacity: int, stack: int, num_envs: int, n_step: int) -> int:
    """Frames a seed's ring holds for ``capacity`` rows (see the module's docstring)."""
    return capacity + capacity // 2 + 2 * recent_frames(stack, n_step) * num_envs


def recent_frames(stack: int, n_step: int) -> int:
    """Frames per env to look a new row's frames up among: its obs' frames were the newest frames of
    the next obs of the rows up to ``n_step`` rows before it."""
    return stack + n_step + 1


def frame_store_bytes(capacity: int, obs_shape: tuple[int, ...], num_envs: int, n_step: int) -> int:
    """What :class:`StackedFrames` holds for one seed: its frames, its rows' serials, and the copies
    of each env's recent frames that new frames are looked up among."""
    stack, *frame = obs_shape
    pixels = math.prod(frame)
    looked_up = num_envs * recent_frames(stack, n_step) * (pixels + 8)
    return frame_capacity(capacity, stack, num_envs, n_step) * pixels + 2 * capacity * stack * 8 + looked_up


class StackedFrames:
    """The pixels of S replay buffers of ``capacity`` rows of ``obs_shape`` ``(stack, H, W)`` uint8
    frame stacks, for ``num_envs`` envs a seed (see the module's docstring)."""

    def __init__(
        self,
        seeds: int,
        capacity: int,
        obs_shape: tuple[int, ...],
        num_envs: int,
        n_step: int,
        device: torch.device,
    ):
        self.stack, *frame_shape = obs_shape
        self.frame_shape = tuple(frame_shape)
        self.capacity = capacity
        recent = recent_frames(self.stack, n_step)
        self.frame_capacity = frame_capacity(capacity, self.stack, num_envs, n_step)
        # Uninitialized (a page costs memory once written), as the replay's table.
        self.frames = torch.empty(
            seeds, self.frame_capacity, *self.frame_shape, dtype=torch.uint8, device=device
        )
        self.frames[:, 0] = 0  # a seed's rows read serial 0 before its first write (padding rows)
        self.index = torch.zeros(2, seeds, capacity, self.stack, dtype=torch.int64, device=device)
        self.serial = np.zeros(seeds, dtype=np.int64)
        """The serial number of each seed's next frame."""
        self.latest = np.full((seeds, num_envs, recent), -1, dtype=np.int64)
        """Each env's last stored frames' serials (-1: none), newest last."""
        self.latest_pixels = np.zeros((seeds, num_envs, recent, math.prod(frame_shape)), dtype=np.uint8)
        """Those frames' pixels, on the host: new frames are looked up here, wherever ``frames`` lives."""
        self.host_view()

    def host_view(self) -> None:
        """On the CPU frames and serials are written through numpy views (cheaper for a few rows)."""
        on_cpu = self.frames.device.type == "cpu"
        self.host_frames = self.frames.numpy() if on_cpu else None
        self.host_index = self.index.numpy() if on_cpu else None

    @property
    def nbytes(self) -> int:
        return self.frames.nbytes + self.index.nbytes + self.latest.nbytes + self.latest_pixels.nbytes

    def write(
        self,
        seed_rows: np.ndarray,
        slots: np.ndarray,
        env_columns: np.ndarray,
        observations: np.ndarray,
        next_observations: np.ndarray,
        live_rows: np.ndarray,
    ) -> None:
        """Rows ``slots`` of seeds ``seed_rows`` get the stacks ``observations`` and
        ``next_observations`` [k, stack, H, W] of envs ``env_columns``; ``live_rows`` [S] is how many
        rows each seed holds after the write (its oldest row then follows the last one written)."""
        serials = np.empty((2, len(slots), self.stack), dtype=np.int64)
        new: list[tuple[int, int, np.ndarray]] = []
        for k, (seed, env) in enumerate(zip(seed_rows.tolist(), env_columns.tolist(), strict=True)):
            for which, stacks in ((OBS, observations), (NEXT, next_observations)):
                serials[which, k] = self.serials_of(seed, env, stacks[k], new)
        self.store_frames(new)
        self.store_serials(seed_rows, slots, serials)
        for seed in np.unique(seed_rows).tolist():
            self.check_room(seed, int(slots[seed_rows == seed][-1]), int(live_rows[seed]))

    def serials_of(
        self, seed: int, env: int, stack: np.ndarray, new: list[tuple[int, int, np.ndarray]]
    ) -> np.ndarray:
        """The serials of ``stack``'s frames: each found among the env's latest frames, else given the
        seed's next serial and added to ``new`` (seed, serial, pixels)."""
        pixels = stack.reshape(self.stack, -1)
        latest, cached = self.latest[seed, env], self.latest_pixels[seed, env]
        serials = np.empty(self.stack, dtype=np.int64)
        same = (pixels[:, None, :] == cached[None, :, :]).all(axis=2) & (latest >= 0)  # [stack, recent]
        for i in range(self.stack):
            found = np.flatnonzero(same[i])
            if found.size:
                serials[i] = latest[found[-1]]
                continue
            serial = int(self.serial[seed])
            self.serial[seed] += 1
            new.append((seed, serial, pixels[i]))
            latest[:-1], cached[:-1] = latest[1:].copy(), cached[1:].copy()
            latest[-1], cached[-1] = serial, pixels[i]
            serials[i] = serial
            same = (pixels[:, None, :] == cached[None, :, :]).all(axis=2) & (latest >= 0)
        return serials

    def store_frames(self, new: list[tuple[int, int, np.ndarray]]) -> None:
        if not new:
            return
        seeds = np.array([seed for seed, _, _ in new], dtype=np.int64)
        slots = np.array([serial for _, serial, _ in new], dtype=np.int64) % self.frame_capacity
        pixels = np.stack([p for _, _, p in new]).reshape(len(new), *self.frame_shape)
        if self.host_frames is not None:
            self.host_frames[seeds, slots] = pixels
            return
        device = self.frames.device
        index = (to_device(torch.from_numpy(seeds), device), to_device(torch.from_numpy(slots), device))
        self.frames[index] = to_device(torch.from_numpy(pixels), device)

    def store_serials(self, seed_rows: np.ndarray, slots: np.ndarray, serials: np.ndarray) -> None:
        if self.host_index is not None:
            self.host_index[:, seed_rows, slots] = serials
            return
        device = self.index.device
        index = (to_device(torch.from_numpy(seed_rows), device), to_device(torch.from_numpy(slots), device))
        self.index[:, index[0], index[1]] = to_device(torch.from_numpy(serials), device)

    def check_room(self, seed: int, last_slot: int, live: int) -> None:
        """No frame a live row uses has been overwritten (a replay of ever shorter episodes could need
        more frames than ``frame_capacity`` holds: then this raises)."""
        oldest_slot = (last_slot + 1) % self.capacity if live == self.capacity else 0
        oldest = int(self.index[:, seed, oldest_slot].min())
        if int(self.serial[seed]) - self.frame_capacity > oldest:
            raise RuntimeError("the replay's frame ring overwrote frames a row still uses")

    def gather(self, index: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The uint8 obs and next obs [S, B, stack, H, W] of rows ``index`` [S, B]."""
        seeds, rows = index.shape
        serials = self.index.gather(2, index.view(1, seeds, rows, 1).expand(2, -1, -1, self.stack))
        base = torch.arange(seeds, device=index.device).view(1, seeds, 1, 1) * self.frame_capacity
        flat = self.frames.view(seeds * self.frame_capacity, *self.frame_shape)
        both = flat.index_select(0, (serials % self.frame_capacity + base).view(-1))
        both = both.view(2, seeds, rows, self.stack, *self.frame_shape)
        return both[OBS], both[NEXT]

    def keep(self, rows_np: np.ndarray) -> None:
        """Keep only the seeds at ``rows_np`` (rising), moved down in place (see StackedReplay.keep)."""
        for new, old in enumerate(rows_np.tolist()):
            if new != old:
                self.frames[new] = self.frames[old]
                self.index[:, new] = self.index[:, old]
        self.frames, self.index = self.frames[: len(rows_np)], self.index[:, : len(rows_np)]
        self.serial, self.latest = self.serial[rows_np], self.latest[rows_np]
        self.latest_pixels = self.latest_pixels[rows_np]
        self.host_view()

    def row_state(self, row: int, size: int) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
        """Seed ``row``'s frames that its ``size`` rows use (oldest serial first), and their serials."""
        index = self.index[:, row, :size].to("cpu", copy=True)
        serial = int(self.serial[row])
        first = int(index.min()) if size else serial
        slots = torch.arange(first, serial) % self.frame_capacity
        frames = self.frames[row].index_select(0, slots.to(self.frames.device)).to("cpu")
        data = {"first_frame": first, "next_frame": serial, "latest": self.latest[row].tolist()}
        return {"frames": frames, "frame_index": index}, data

    def load_row_state(self, row: int, tensors: dict[str, torch.Tensor], data: dict[str, Any]) -> None:
        first, serial = int(data["first_frame"]), int(data["next_frame"])
        frames = tensors["frames"]
        slots = torch.arange(first, serial) % self.frame_capacity
        self.frames[row].index_copy_(0, slots.to(self.frames.device), frames.to(self.frames.device))
        index = tensors["frame_index"]
        self.index[:, row, : index.shape[1]] = index.to(self.index.device)
        self.serial[row] = serial
        latest = np.asarray(data["latest"], dtype=np.int64)
        latest[latest < first] = -1  # not saved: a frame stored again if it comes back
        self.latest[row] = latest
        for env, serials in enumerate(latest):
            for i, s in enumerate(serials.tolist()):
                if s >= 0:
                    self.latest_pixels[row, env, i] = frames[s - first].reshape(-1).numpy()


__all__ = ["StackedFrames", "frame_capacity", "frame_store_bytes"]
