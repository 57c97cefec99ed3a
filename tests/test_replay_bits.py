"""Replay's binary columns (the wall map's 0 / 1 squares) kept as uint8: every sample, n-step return, static-buffer
sample and saved state equals that of the all-float buffer, at a quarter of those columns' memory."""

from __future__ import annotations

import pytest
import torch

from flashnav.learn.replay import Replay, Transition

N, D, A, B = 3, 11, 2, 8   # the last B of D observation columns are 0 / 1


def _stream(steps: int, seed: int):
    """Random per-env streams whose observations end in B columns of 0 / 1 (the float ones random)."""
    g = torch.Generator().manual_seed(seed)

    def obs():
        floats = torch.randn(steps, N, D - B, generator=g)
        return torch.cat((floats, (torch.rand(steps, N, B, generator=g) < 0.3).float()), dim=-1)

    first, action, reward = obs(), torch.randn(steps, N, A, generator=g), torch.randn(steps, N, generator=g)
    terminated = torch.rand(steps, N, generator=g) < 0.15
    ended = terminated | (torch.rand(steps, N, generator=g) < 0.1)
    return first, action, reward, terminated, obs(), ended


def _filled(bits: int, steps: int, n_step: int, capacity: int = 30, stream=None) -> Replay:
    replay = Replay(N, D, A, capacity, seed=5, n_step=n_step, gamma=0.9 if n_step > 1 else None, binary_columns=bits)
    obs, action, reward, terminated, next_obs, ended = stream or _stream(steps, seed=steps + n_step)
    for t in range(steps):
        replay.add(obs[t], action[t], reward[t], terminated[t], next_obs[t], ended[t])
    return replay


@pytest.mark.parametrize("steps", [6, 17])        # before and after the buffer (10 rows an env) wraps
@pytest.mark.parametrize("n_step", [1, 3])
def test_uint8_columns_sample_what_float_columns_do(steps, n_step):
    plain, packed = _filled(0, steps, n_step), _filled(B, steps, n_step)
    assert packed.obs_bits.dtype == torch.uint8 and packed.obs.shape[-1] == D - B and plain.obs_bits is None
    assert packed.obs.nbytes + packed.obs_bits.nbytes == plain.obs.nbytes * (D - B + B / 4) / D
    for _ in range(3):
        for x, y in zip(plain.sample(16, 2), packed.sample(16, 2)):
            assert x.dtype == y.dtype == torch.float32 and torch.equal(x, y)
    # into static buffers (the CUDA-graph path): the same rows and values
    shapes = ((2, 16, D), (2, 16, A), (2, 16), (2, 16), (2, 16, D))
    outs = [Transition(*(torch.full(s, -7.0) for s in shapes)) for _ in range(2)]
    for x, y in zip(plain.sample(16, 2, out=outs[0]), packed.sample(16, 2, out=outs[1])):
        assert torch.equal(x, y)
    assert set(outs[1].obs[..., D - B:].unique().tolist()) <= {0.0, 1.0}


@pytest.mark.parametrize("saved_bits, loaded_bits", [(B, B), (B, 0), (0, B), (B, 3)])
def test_a_state_moves_between_float_and_uint8_columns(saved_bits, loaded_bits):
    """A replay.pt loads into a buffer that splits its columns otherwise (a file written before the uint8 columns
    reads as saved_bits 0): the rows and the next samples are those of the buffer that was saved."""
    stream = _stream(8, seed=1)
    saved = _filled(saved_bits, 8, 3, capacity=60, stream=stream)
    state = saved.state_dict()
    assert state["binary_columns"] == saved_bits and state["format"] == Replay.FORMAT
    if saved_bits == 0:  # as format 1 wrote it
        state = {k: v for k, v in state.items() if k != "binary_columns"} | {"format": 1}
    loaded = Replay(N, D, A, 60, seed=99, n_step=3, gamma=0.9, binary_columns=loaded_bits)
    loaded.load_state_dict(state)
    reference = _filled(0, 8, 3, capacity=60, stream=stream)
    loaded.ended[7] = reference.ended[7]  # the seam mark aside, the rows are the saved ones
    for x, y in zip(reference.sample(16, 2), loaded.sample(16, 2)):
        assert torch.equal(x, y)


def test_a_newer_layout_is_refused_by_name():
    state = _filled(B, 4, 1).state_dict() | {"format": Replay.FORMAT + 1}
    said = rf"my replay.pt: replay layout format {Replay.FORMAT + 1}, this FlashNav reads up to"
    with pytest.raises(ValueError, match=said):
        Replay(N, D, A, 30, binary_columns=B).load_state_dict(state, "my replay.pt")


def test_binary_columns_out_of_range_are_refused_by_name():
    for bad in (-1, D + 1, 2.0):
        with pytest.raises(ValueError, match=r"binary_columns must be an integer in \[0, obs_dim=11\]"):
            Replay(N, D, A, 12, binary_columns=bad)
