"""Replay buffer: layout, wrap-around, sampling validity and reproducibility."""

import re

import pytest
import torch

from flashnav.learn.replay import Replay, Transition

N, D, A = 3, 5, 2


def step_data(step: int, n: int = N):
    """Transitions whose every field encodes (step, env) so a sample can be traced to its origin."""
    env = torch.arange(n, dtype=torch.float32)
    code = 100.0 * (step + 1) + env                                   # never 0: unwritten rows are 0
    obs = code[:, None].expand(n, D).clone()
    action = torch.stack([code / 1000.0, -code / 1000.0], -1) * 2    # some beyond [-1, 1]
    return obs, action, code, (env == 1), obs + 0.5


def fill(replay: Replay, steps: int, start: int = 0):
    for t in range(start, start + steps):
        replay.add(*step_data(t))


def test_capacity_rounds_up_to_whole_vector_steps():
    replay = Replay(N, D, A, capacity=10)
    assert replay.rows_per_env == 4 and replay.capacity == 12 and replay.size == 0


def test_add_stores_clamped_actions_and_float_terminated():
    replay = Replay(N, D, A, capacity=12)
    fill(replay, 1)
    assert replay.size == N
    assert replay.action.abs().max() <= 1.0
    torch.testing.assert_close(replay.terminated[0], torch.tensor([0.0, 1.0, 0.0]))
    torch.testing.assert_close(replay.next_obs[0], replay.obs[0] + 0.5)


def test_samples_only_written_rows_before_wrap():
    replay = Replay(N, D, A, capacity=30, seed=1)
    fill(replay, 2)
    batch = replay.sample(batch_size=500, n_batches=3)
    codes = set(batch.reward.flatten().tolist())
    assert codes <= {100.0, 101.0, 102.0, 200.0, 201.0, 202.0}
    assert len(codes) == 6   # every stored transition is reachable


def test_wrap_around_overwrites_oldest_and_keeps_fields_aligned():
    replay = Replay(N, D, A, capacity=12, seed=2)          # 4 slots per env
    fill(replay, 6)                                          # steps 0, 1 overwritten by 4, 5
    assert replay.size == 12
    batch = replay.sample(batch_size=1000, n_batches=2)
    steps = set((batch.reward // 100).long().flatten().tolist())
    assert steps == {3, 4, 5, 6}                             # codes of steps 2..5
    # fields of one sampled row belong to the same transition
    torch.testing.assert_close(batch.obs[..., 0], batch.reward)
    torch.testing.assert_close(batch.next_obs[..., 0], batch.reward + 0.5)
    torch.testing.assert_close(batch.bootstrap, (batch.reward % 100 != 1).float())


def test_sample_shapes_and_at():
    replay = Replay(N, D, A, capacity=12)
    fill(replay, 3)
    batch = replay.sample(batch_size=7, n_batches=4)
    assert isinstance(batch, Transition)
    assert batch.obs.shape == (4, 7, D) and batch.action.shape == (4, 7, A)
    assert batch.reward.shape == (4, 7) and batch.bootstrap.shape == (4, 7) and batch.next_obs.shape == (4, 7, D)
    one = batch.at(2)
    assert one.obs.shape == (7, D) and torch.equal(one.reward, batch.reward[2])
    assert all(x.dtype == torch.float32 for x in batch)


def test_sampling_is_reproducible_with_a_seed():
    a, b, c = Replay(N, D, A, 12, seed=7), Replay(N, D, A, 12, seed=7), Replay(N, D, A, 12, seed=8)
    for replay in (a, b, c):
        fill(replay, 5)
    sa, sb, sc = a.sample(64, 3), b.sample(64, 3), c.sample(64, 3)
    assert torch.equal(sa.reward, sb.reward) and torch.equal(sa.obs, sb.obs)
    assert not torch.equal(sa.reward, sc.reward)


def test_errors_and_clear():
    replay = Replay(N, D, A, 12)
    with pytest.raises(ValueError):
        replay.sample(4)
    with pytest.raises(ValueError):
        replay.add(torch.zeros(N, D + 1), torch.zeros(N, A), torch.zeros(N), torch.zeros(N), torch.zeros(N, D))
    fill(replay, 2)
    replay.clear()
    assert replay.size == 0


def test_sample_into_static_buffers_gives_the_same_rows_and_draws():
    # Replay.sample(out=...) is how the CUDA-graph path fills its static buffers: the same values as a
    # fresh sample from the same generator state, written in place, and the generator advanced alike.
    a, b = Replay(N, D, A, capacity=30, seed=4), Replay(N, D, A, capacity=30, seed=4)
    fill(a, 12)  # wrapped: rows from every slot
    fill(b, 12)
    out = Transition(torch.full((3, 7, D), -1.0), torch.full((3, 7, A), -1.0), torch.full((3, 7), -1.0),
                     torch.full((3, 7), -1.0), torch.full((3, 7, D), -1.0))
    addresses = [x.data_ptr() for x in out]
    for _ in range(2):
        want, got = a.sample(7, 3), b.sample(7, 3, out=out)
        assert got is out and [x.data_ptr() for x in got] == addresses
        for name, w, g in zip(Transition._fields, want, got):
            assert torch.equal(w, g), name
    assert torch.equal(a.generator.get_state(), b.generator.get_state())


def test_sample_out_names_the_field_that_does_not_fit():
    replay = Replay(N, D, A, capacity=12)
    fill(replay, 2)
    good = [torch.zeros(2, 4, D), torch.zeros(2, 4, A), torch.zeros(2, 4), torch.zeros(2, 4), torch.zeros(2, 4, D)]
    bad_shape = Transition(*good[:1], torch.zeros(2, 4, A + 1), *good[2:])
    with pytest.raises(ValueError, match=r"action must be .*\(2, 4, 2\).*got .*\(2, 4, 3\)"):
        replay.sample(4, 2, out=bad_shape)
    bad_dtype = Transition(*good[:2], torch.zeros(2, 4, dtype=torch.float64), *good[3:])
    with pytest.raises(ValueError, match="reward must be a contiguous torch.float32"):
        replay.sample(4, 2, out=bad_dtype)
    strided = Transition(*good[:4], torch.zeros(2, 4, D * 2)[..., ::2])
    with pytest.raises(ValueError, match="next_obs must be a contiguous"):
        replay.sample(4, 2, out=strided)
    # the device is the stored rows' own: a replay made on "cpu:0" (as "cuda" on a GPU, whose tensors live on
    # "cuda:0") takes buffers on "cpu" (found by the first CUDA run: "cuda" != "cuda:0")
    indexed = Replay(N, D, A, capacity=12, device="cpu:0")
    fill(indexed, 2)
    assert indexed.sample(4, 2, out=Transition(*good)).obs.shape == (2, 4, D)


# --- n-step returns -------------------------------------------------------------------------------

def _episodes(steps: int, n: int, seed: int):
    """Random per-env streams: rewards, terminated and truncated flags (episodes of a few steps)."""
    g = torch.Generator().manual_seed(seed)
    reward = torch.randn(steps, n, generator=g)
    terminated = torch.rand(steps, n, generator=g) < 0.15
    truncated = ~terminated & (torch.rand(steps, n, generator=g) < 0.1)
    obs = torch.randn(steps, n, D, generator=g)
    next_obs = torch.randn(steps, n, D, generator=g)
    return obs, reward, terminated, truncated, next_obs


def _reference(stream, step: int, env: int, newest: int, n_step: int, gamma: float):
    """The n-step transition of (step, env), written out the obvious way over the time-ordered stream."""
    obs, reward, terminated, truncated, next_obs = stream
    total, last = 0.0, step
    for k in range(n_step):
        s = step + k
        if s > newest:
            break
        total += gamma ** k * float(reward[s, env])
        last = s
        if terminated[s, env] or truncated[s, env]:
            break
    m = last - step + 1
    bootstrap = gamma ** (m - 1) * (0.0 if terminated[last, env] else 1.0)
    return obs[step, env], total, bootstrap, next_obs[last, env]


@pytest.mark.parametrize("steps, capacity", [(9, 60), (23, 30)])   # before and after the buffer wraps
@pytest.mark.parametrize("n_step", [2, 3, 5])
def test_n_step_returns_equal_a_reference(steps, capacity, n_step):
    n, gamma = 3, 0.9
    stream = _episodes(steps, n, seed=steps + n_step)
    obs, reward, terminated, truncated, next_obs = stream
    replay = Replay(n, D, A, capacity=capacity, seed=3, n_step=n_step, gamma=gamma)
    for t in range(steps):
        replay.add(obs[t], torch.zeros(n, A), reward[t], terminated[t], next_obs[t], terminated[t] | truncated[t])
    batch = replay.sample(400, 2)
    oldest = steps - replay.rows_per_env if steps > replay.rows_per_env else 0
    seen = set()
    for u in range(2):
        for i in range(400):
            # find the sampled (step, env) from its observation (random normals: unique)
            hit = (obs[oldest:] == batch.obs[u, i]).all(-1).nonzero()
            assert hit.shape[0] == 1, "every sample is one stored row"
            step, env = int(hit[0, 0]) + oldest, int(hit[0, 1])
            seen.add((step, env))
            want_obs, want_r, want_b, want_next = _reference(stream, step, env, steps - 1, n_step, gamma)
            assert abs(float(batch.reward[u, i]) - want_r) < 1e-5
            assert abs(float(batch.bootstrap[u, i]) - want_b) < 1e-6
            assert torch.equal(batch.next_obs[u, i], want_next)
    assert len(seen) > 0.8 * (steps - oldest) * n   # the draws cover the buffer (incl. its newest rows)


def test_n_step_sample_into_static_buffers_matches():
    stream = _episodes(12, N, seed=5)
    a, b = (Replay(N, D, A, capacity=30, seed=4, n_step=3, gamma=0.97) for _ in range(2))
    for replay in (a, b):
        for t in range(12):
            replay.add(stream[0][t], torch.zeros(N, A), stream[1][t], stream[2][t], stream[4][t],
                       stream[2][t] | stream[3][t])
    out = Transition(*(torch.full_like(x, -1.0) for x in a.sample(7, 3)))
    a.generator.manual_seed(9)
    b.generator.manual_seed(9)
    want, got = a.sample(7, 3), b.sample(7, 3, out=out)
    assert got is out
    for name, w, g in zip(Transition._fields, want, got):
        assert torch.equal(w, g), name


def test_one_step_is_the_stored_transition_and_n_step_needs_its_inputs():
    stream = _episodes(6, N, seed=1)
    one = Replay(N, D, A, capacity=30, seed=2)
    for t in range(6):
        one.add(stream[0][t], torch.zeros(N, A), stream[1][t], stream[2][t], stream[4][t])
    batch = one.sample(50)
    flat_obs = stream[0].reshape(-1, D)
    for i in range(50):
        row = int((flat_obs == batch.obs[0, i]).all(-1).nonzero()[0, 0])
        assert float(batch.reward[0, i]) == float(stream[1].reshape(-1)[row])
        assert float(batch.bootstrap[0, i]) == 1.0 - float(stream[2].reshape(-1)[row])
    with pytest.raises(ValueError, match="n_step must be an integer >= 1"):
        Replay(N, D, A, 12, n_step=0)
    with pytest.raises(ValueError, match="needs the discount gamma"):
        Replay(N, D, A, 12, n_step=3)
    three = Replay(N, D, A, 12, n_step=3, gamma=0.99)
    with pytest.raises(ValueError, match=re.escape("ended=terminated | truncated")):
        three.add(stream[0][0], torch.zeros(N, A), stream[1][0], stream[2][0], stream[4][0])
