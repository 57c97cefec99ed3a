"""Random shifts of the wall map in replay batches (algo.wall_shift; flashnav/learn/wall_shift.py): the vectorised
shift equals a square-by-square loop on random maps, touches the map's columns and nothing else, draws after the
rows and the mirror (so a run without it samples as before), refuses what it cannot shift, and reaches the updates of
a training run."""

from __future__ import annotations

import pytest
import torch

from flashnav.learn.mirror import mirror_for
from flashnav.learn.replay import Replay, Transition
from flashnav.learn.wall_shift import WallShift, wall_shift_for
from flashnav.presets import load_robot

CELLS = 7
PRESET = load_robot("turtlebot2", **{"observation.wall_map": CELLS})


def loop_shift(obs: torch.Tensor, start: int, cells: int, dr: int, dc: int, channels: int = 2) -> torch.Tensor:
    """One row's map moved by (dr, dc) squares, one square at a time; squares from beyond the map are 0."""
    out = obs.clone()
    for ch in range(channels):
        base = start + ch * cells * cells
        for i in range(cells):
            for j in range(cells):
                si, sj = i - dr, j - dc
                inside = 0 <= si < cells and 0 <= sj < cells
                out[base + i * cells + j] = obs[base + si * cells + sj] if inside else 0.0
    return out


@pytest.mark.parametrize("cells,reach,lead,channels", [(7, 1, (5,), 2), (5, 2, (3, 4), 2), (2, 1, (6,), 2),
                                                       (5, 2, (3, 4), 3)])
def test_the_shift_is_the_square_by_square_loop(cells, reach, lead, channels):
    start, tail = 9, 3
    gen = torch.Generator().manual_seed(cells * 10 + reach)
    obs = torch.rand(*lead, start + channels * cells * cells + tail, generator=gen)
    shift = WallShift(start=start, cells=cells, reach=reach, channels=channels)
    got = shift.shifted(obs, torch.Generator().manual_seed(3))
    draws = torch.Generator().manual_seed(3)
    n = obs[..., 0].numel()
    dr = torch.randint(-reach, reach + 1, (n, 1), generator=draws)
    dc = torch.randint(-reach, reach + 1, (n, 1), generator=draws)
    flat = obs.reshape(n, -1)
    want = torch.stack([loop_shift(flat[k], start, cells, int(dr[k]), int(dc[k]), channels) for k in range(n)])
    torch.testing.assert_close(got.reshape(n, -1), want[:, start: start + channels * cells * cells], rtol=0, atol=0)
    assert {int(v) for v in dr} | {int(v) for v in dc} <= set(range(-reach, reach + 1))


def test_a_shift_moves_walls_and_goal_together():
    obs = torch.zeros(1, PRESET.obs_dim)
    start = PRESET.memory_end
    obs[0, start + 3 * CELLS + 3] = 1.0              # a wall at (3, 3)
    obs[0, start + CELLS * CELLS + 3 * CELLS + 4] = 1.0  # the goal at (3, 4)
    shift = wall_shift_for(PRESET, 2)
    for seed in range(20):
        got = shift.shifted(obs, torch.Generator().manual_seed(seed)).reshape(2, CELLS, CELLS)
        (wr, wc), (gr, gc) = (torch.nonzero(got[ch])[0].tolist() for ch in range(2))
        assert (gr - wr, gc - wc) == (0, 1) and abs(wr - 3) <= 2 and abs(wc - 3) <= 2
        assert got.sum() == 2


def _filled(shift: WallShift | None, mirror: float = 0.0) -> Replay:
    gen = torch.Generator().manual_seed(0)
    r = Replay(4, PRESET.obs_dim, 2, 64, seed=5, mirror=mirror_for(PRESET, mirror), wall_shift=shift)
    for _ in range(16):
        d = PRESET.obs_dim
        r.add(torch.rand(4, d, generator=gen).round(), torch.rand(4, 2, generator=gen) * 2 - 1,
              torch.randn(4, generator=gen), torch.zeros(4), torch.rand(4, d, generator=gen).round())
    return r


@pytest.mark.parametrize("mirror", [0.0, 0.5])
def test_replay_shifts_the_map_columns_only_after_every_other_draw(mirror):
    base = _filled(None, mirror).sample(64, 3)
    shift = wall_shift_for(PRESET, 1)
    r = _filled(shift, mirror)
    stored = r.obs.clone()
    got = r.sample(64, 3)
    torch.testing.assert_close(r.obs, stored)  # the buffer itself is never touched
    end = PRESET.memory_end
    for x, y in ((got.obs, base.obs), (got.next_obs, base.next_obs)):
        assert torch.equal(x[..., :end], y[..., :end])
        assert not torch.equal(x[..., end:], y[..., end:])
    assert torch.equal(got.action, base.action) and torch.equal(got.reward, base.reward)
    # the same draws give the same shifts: replaying the generator after the rows and mirror reproduces the batch
    again = _filled(shift, mirror)
    out = Transition(*(torch.empty_like(x) for x in base))
    torch.testing.assert_close(tuple(again.sample(64, 3, out=out)), tuple(got), rtol=0, atol=0)


def test_wall_shift_refuses_what_it_cannot_shift():
    assert wall_shift_for(PRESET, 0) is None
    with pytest.raises(ValueError, match="turtlebot2 has none .*robot.observation.wall_map"):
        wall_shift_for(load_robot("turtlebot2"), 1)
    with pytest.raises(ValueError, match=f"algo.wall_shift=7 would move .*7 x 7 .*at most 6"):
        wall_shift_for(PRESET, 7)
    with pytest.raises(ValueError, match="algo.wall_shift must be .* got -1"):
        wall_shift_for(PRESET, -1)
    with pytest.raises(ValueError, match="wall_shift reads columns up to"):
        Replay(4, PRESET.memory_end, 2, 64, wall_shift=wall_shift_for(PRESET, 1))


def test_training_with_the_shift_reaches_the_updates_and_is_seeded():
    from flashnav import train
    from tests.test_train import TINY, flat, tiny

    over = {**TINY, "robot.observation.wall_map": 4}
    shifted = train(tiny(overrides={**over, "algo.wall_shift": 1}))
    assert shifted.spec.hparams.wall_shift == 1
    plain = train(tiny(overrides=over))
    a = flat(shifted.learner.policy)
    assert not torch.equal(a, flat(plain.learner.policy))  # the shifted maps reached the updates
    assert torch.equal(a, flat(train(tiny(overrides={**over, "algo.wall_shift": 1})).learner.policy))
    with pytest.raises(ValueError, match="algo.wall_shift=1 shifts the wall map"):
        train(tiny(overrides={**TINY, "algo.wall_shift": 1}))
