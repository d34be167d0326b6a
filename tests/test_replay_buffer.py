"""The replay buffer's invariants: ring order, wrap-around, sampling only written rows, exact resume."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from cartpole.agents.replay_buffer import Batch, ReplayBuffer

FIELDS = ("observations", "actions", "rewards", "next_observations", "terminated")


def rows(start: int, n: int, obs_dim: int = 3) -> tuple[np.ndarray, ...]:
    """n transitions whose every field encodes its global index (start .. start+n-1)."""
    index = np.arange(start, start + n)
    obs = np.repeat(index[:, None], obs_dim, axis=1).astype(np.float32)
    return obs, index.astype(np.int64), index.astype(np.float32), obs + 0.5, (index % 2).astype(np.float32)


def generator(seed: int) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


def test_storage_is_preallocated_tensors_on_the_device() -> None:
    buffer = ReplayBuffer(10, 3)
    assert buffer.observations.shape == (10, 3) and buffer.observations.dtype == torch.float32
    assert buffer.table.shape == (10, 2 * 3 + 3)  # one row per transition: all fields side by side
    assert all(getattr(buffer, name).data_ptr() >= buffer.table.data_ptr() for name in FIELDS)
    assert all(getattr(buffer, name).device == torch.device("cpu") for name in FIELDS)


def test_batches_have_the_documented_dtypes_and_shapes() -> None:
    buffer = ReplayBuffer(10, 3)
    buffer.add(*rows(0, 6))
    batch = buffer.sample(5, generator(0))
    assert batch.observations.shape == batch.next_observations.shape == (5, 3)
    assert batch.actions.shape == (5,) and batch.actions.dtype == torch.int64
    for name in ("observations", "rewards", "next_observations", "terminated"):
        assert getattr(batch, name).dtype == torch.float32
    np.testing.assert_array_equal(batch.actions.numpy(), batch.rewards.numpy())  # same row, same index


def test_add_keeps_rows_in_order_until_full() -> None:
    buffer = ReplayBuffer(10, 3)
    buffer.add(*rows(0, 4))
    buffer.add(*rows(4, 3))
    assert len(buffer) == 7 and buffer.pos == 7
    np.testing.assert_array_equal(buffer.actions[:7].numpy(), np.arange(7))
    np.testing.assert_array_equal(buffer.next_observations[:7, 0].numpy(), np.arange(7) + 0.5)


def test_wrap_around_overwrites_the_oldest_rows() -> None:
    buffer = ReplayBuffer(5, 3)
    buffer.add(*rows(0, 4))
    buffer.add(*rows(4, 3))  # rows 4, 5, 6: 5 and 6 wrap onto slots 0 and 1
    assert len(buffer) == 5 and buffer.pos == 2
    np.testing.assert_array_equal(buffer.actions.numpy(), [5, 6, 2, 3, 4])
    np.testing.assert_array_equal(buffer.rewards.numpy(), [5, 6, 2, 3, 4])
    np.testing.assert_array_equal(buffer.terminated.numpy(), [1, 0, 0, 1, 0])


def test_adding_more_than_capacity_keeps_the_newest() -> None:
    buffer = ReplayBuffer(4, 3)
    buffer.add(*rows(0, 1))
    buffer.add(*rows(1, 10))  # indices 1..10; the newest four are 7..10
    assert len(buffer) == 4
    assert buffer.pos == (1 + 10) % 4
    assert sorted(buffer.actions.tolist()) == [7, 8, 9, 10]
    # ring order is kept: the slot before pos holds the newest row
    assert buffer.actions[(buffer.pos - 1) % 4] == 10


def test_the_device_write_path_matches_the_host_one() -> None:
    """Off CPU, rows are written with index_copy_; here that path runs on CPU against the numpy one."""
    host, device_path = ReplayBuffer(5, 3), ReplayBuffer(5, 3)
    device_path._host_views = None
    for start, n in ((0, 4), (4, 3), (7, 12)):  # in order, wrapping, more than capacity
        host.add(*rows(start, n))
        device_path.add(*rows(start, n))
        assert (host.pos, host.size) == (device_path.pos, device_path.size)
        for name in FIELDS:
            assert torch.equal(getattr(host, name), getattr(device_path, name)), name


def test_empty_add_is_a_no_op() -> None:
    buffer = ReplayBuffer(4, 3)
    buffer.add(*(r[:0] for r in rows(0, 2)))
    assert len(buffer) == 0 and buffer.pos == 0


def test_sampling_only_returns_written_rows() -> None:
    buffer = ReplayBuffer(1000, 3)
    buffer.add(*rows(100, 7))  # slots 0..6 hold indices 100..106; the rest are zeros
    gen = generator(0)
    for _ in range(50):
        batch = buffer.sample(32, gen)
        assert isinstance(batch, Batch)
        actions = batch.actions.numpy()
        assert ((actions >= 100) & (actions <= 106)).all()
        # every field of a sampled row belongs to the same transition
        np.testing.assert_array_equal(batch.observations[:, 0].numpy(), actions)
        np.testing.assert_array_equal(batch.rewards.numpy(), actions)
        np.testing.assert_array_equal(batch.next_observations[:, 0].numpy(), actions + 0.5)
        np.testing.assert_array_equal(batch.terminated.numpy(), actions % 2)


def test_sample_dtypes_and_shapes() -> None:
    buffer = ReplayBuffer(16, 3)
    buffer.add(*rows(0, 8))
    batch = buffer.sample(5, generator(1))
    assert batch.observations.shape == (5, 3) and batch.observations.dtype == torch.float32
    assert batch.actions.shape == (5,) and batch.actions.dtype == torch.int64
    assert batch.rewards.dtype == torch.float32 and batch.terminated.dtype == torch.float32


def test_a_sample_is_a_copy_not_a_view_of_the_storage() -> None:
    buffer = ReplayBuffer(4, 3)
    buffer.add(*rows(0, 4))
    batch = buffer.sample(8, generator(0))
    buffer.add(*rows(10, 4))  # overwrite every row
    assert int(batch.actions.max()) < 4


def test_sampling_is_uniform_over_written_rows() -> None:
    buffer = ReplayBuffer(8, 3)
    buffer.add(*rows(0, 8))
    counts = np.bincount(buffer.sample(80_000, generator(2)).actions.numpy(), minlength=8)
    assert np.all(np.abs(counts / 80_000 - 1 / 8) < 0.01)


def test_sampling_is_determined_by_the_generator() -> None:
    buffer = ReplayBuffer(100, 3)
    buffer.add(*rows(0, 60))
    a, b, c = generator(5), generator(5), generator(6)
    first = [buffer.sample(16, a).actions for _ in range(3)]
    assert all(torch.equal(x, buffer.sample(16, b).actions) for x in first)
    assert not all(torch.equal(x, buffer.sample(16, c).actions) for x in first)
    # the generator's state (a tensor: what checkpoints save) resumes the exact stream
    state = a.get_state()
    expected = buffer.sample(16, a).actions
    resumed = torch.Generator()
    resumed.set_state(state.clone())
    assert torch.equal(buffer.sample(16, resumed).actions, expected)


def test_empty_buffer_cannot_be_sampled() -> None:
    with pytest.raises(ValueError, match="empty"):
        ReplayBuffer(4, 3).sample(1, generator(0))


def test_bad_capacity_is_rejected() -> None:
    with pytest.raises(ValueError, match="capacity"):
        ReplayBuffer(0, 3)


def test_state_dict_round_trip_continues_exactly() -> None:
    buffer = ReplayBuffer(6, 3)
    buffer.add(*rows(0, 9))
    tensors, data = buffer.state_dict()
    assert all(t.shape[0] == len(buffer) for t in tensors.values())  # only the written rows
    copy = ReplayBuffer(6, 3)
    copy.load_state_dict(tensors, data)
    assert (copy.pos, copy.size) == (buffer.pos, buffer.size)
    buffer.add(*rows(9, 2))
    copy.add(*rows(9, 2))  # through the numpy views, which the load must have kept valid
    for name in FIELDS:
        assert torch.equal(getattr(copy, name), getattr(buffer, name)), name
    a, b = buffer.sample(16, generator(3)), copy.sample(16, generator(3))
    assert all(torch.equal(x, y) for x, y in zip(a, b, strict=True))


def test_state_dict_is_a_snapshot() -> None:
    buffer = ReplayBuffer(6, 3)
    buffer.add(*rows(0, 3))
    tensors, _ = buffer.state_dict()
    buffer.add(*rows(3, 6))
    assert tensors["actions"].tolist() == [0, 1, 2]


def test_load_rejects_another_capacity() -> None:
    buffer = ReplayBuffer(6, 3)
    buffer.add(*rows(0, 2))
    with pytest.raises(ValueError, match="capacity"):
        ReplayBuffer(7, 3).load_state_dict(*buffer.state_dict())
