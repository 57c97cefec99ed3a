"""A run's replay buffer carried into the next run: ``Replay.state_dict`` / ``load_state_dict``, ``replay.pt``
(``flashnav train --save-replay``) and ``init_replay`` (``--init-from RUN --init-replay``, issue 15 item 5's
"replay optional")."""

from __future__ import annotations

import pytest
import torch

from flashnav import train
from flashnav.checkpoint import load_replay, save_replay
from flashnav.learn.artefacts import RUN_FILES, save_run
from flashnav.learn.replay import Replay
from flashnav.names import REPLAY_FILE
from flashnav.spec import RunSpec, resolve
from tests.test_replay import D, _episodes, _reference
from tests.test_train import tiny

N = 3


def _add(replay: Replay, stream, steps: range) -> None:
    obs, reward, terminated, truncated, next_obs = stream
    for t in steps:
        replay.add(obs[t], torch.zeros(N, 2), reward[t], terminated[t], next_obs[t], terminated[t] | truncated[t])


def _every_row(replay: Replay):
    """(obs, reward, bootstrap, next_obs) of every stored row, in flat row order."""
    obs, _, reward, bootstrap, next_obs = replay._gather(torch.arange(replay.size)[None], 1, replay.size, None).at(0)
    return obs, reward, bootstrap, next_obs


@pytest.mark.parametrize("saved_steps, new_capacity", [(7, 60), (25, 60), (25, 30), (25, 12)])
@pytest.mark.parametrize("n_step", [1, 3])
def test_a_loaded_buffer_holds_the_newest_saved_steps_and_returns_stop_at_the_seam(saved_steps, new_capacity, n_step):
    """Saved before or after the buffer wrapped (capacity 30 = 10 rows per env), loaded into a buffer as large, larger
    or smaller, then 4 more steps added: every row's n-step transition equals the reference written over the stream
    of the kept steps and the new ones, the seam between them an episode end (truncated, not terminated)."""
    gamma = 0.9
    saved, later = _episodes(saved_steps, N, seed=1), _episodes(4, N, seed=2)
    old = Replay(N, D, 2, 30, n_step=n_step, gamma=gamma)
    _add(old, saved, range(saved_steps))
    state = old.state_dict()
    new = Replay(N, D, 2, new_capacity, n_step=n_step, gamma=gamma, seed=5)
    new.load_state_dict(state)
    kept = min(saved_steps, old.rows_per_env, new.rows_per_env)
    assert new.size == kept * N
    _add(new, later, range(4))
    stream = [torch.cat([a[saved_steps - kept:], b]) for a, b in zip(saved, later)]
    stream[3] = stream[3].clone()
    stream[3][kept - 1] |= ~stream[2][kept - 1]  # the seam: the last kept step of every env ends its episode
    total = kept + 4
    first = max(0, total - new.rows_per_env)  # steps the new buffer overwrote when it wrapped in turn
    obs, reward, bootstrap, next_obs = _every_row(new)
    for step in range(first, total):
        slot = step % new.rows_per_env
        for env in range(N):
            row = slot * N + env
            want = _reference(stream, step, env, total - 1, n_step, gamma)
            assert torch.equal(obs[row], want[0])
            assert reward[row].item() == pytest.approx(want[1], abs=1e-5)
            assert bootstrap[row].item() == pytest.approx(want[2], abs=1e-6)
            assert torch.equal(next_obs[row], want[3])


def test_a_round_trip_samples_bit_for_bit_as_the_saved_buffer_goes_on():
    """Not wrapped, same capacity: the rows, the write position and the generator come back, so the next samples
    (mirror-free rows, n-step returns) equal those of the buffer that was saved."""
    stream = _episodes(8, N, seed=3)
    a = Replay(N, D, 2, 60, n_step=3, gamma=0.9, seed=7)
    _add(a, stream, range(8))
    a.sample(4)  # the generator has moved on
    b = Replay(N, D, 2, 60, n_step=3, gamma=0.9, seed=99)
    b.load_state_dict(a.state_dict())
    for x, y in zip(a.sample(16, 2), b.sample(16, 2)):
        assert torch.equal(x, y)


def test_a_mismatched_buffer_is_refused_by_name():
    stream = _episodes(5, N, seed=4)
    one_step = Replay(N, D, 2, 30)
    _add(one_step, stream, range(5))
    state = one_step.state_dict()
    with pytest.raises(ValueError, match=r"replay\.pt: saved with num_envs 3, this run's replay has 4"):
        Replay(4, D, 2, 30).load_state_dict(state, "replay.pt")
    with pytest.raises(ValueError, match="saved with obs_dim 5, this run's replay has 6"):
        Replay(N, D + 1, 2, 30).load_state_dict(state)
    with pytest.raises(ValueError, match="saved without episode ends"):
        Replay(N, D, 2, 30, n_step=3, gamma=0.9).load_state_dict(state)


def test_replay_files_load_safely_and_name_a_bad_file(tmp_path):
    replay = Replay(N, D, 2, 30, n_step=2, gamma=0.9)
    _add(replay, _episodes(4, N, seed=5), range(4))
    path = save_replay(tmp_path / REPLAY_FILE, replay.state_dict())
    back = load_replay(path)
    assert torch.equal(back["rows"]["obs"], replay.obs[:4]) and back["num_envs"] == N
    with pytest.raises(FileNotFoundError, match="no such replay file"):
        load_replay(tmp_path / "none.pt")
    (tmp_path / "junk.pt").write_bytes(b"junk")
    with pytest.raises(ValueError, match="junk.pt: not a readable FlashNav replay"):
        load_replay(tmp_path / "junk.pt")
    torch.save({"format_version": 9, "replay": {}}, tmp_path / "future.pt")
    with pytest.raises(ValueError, match="not a FlashNav replay of format_version 1 \\(found 9\\)"):
        load_replay(tmp_path / "future.pt")


def test_a_run_continues_with_its_replay(tmp_path):
    """train(keep_replay=True) and save_run(replay=True) write replay.pt; init_replay starts the next run from it (no warm-up: it updates from
    its first vector step), the config records it and reads back; without replay=True a stale replay.pt goes."""
    plain = train(tiny())
    assert plain.replay is None  # kept only when asked for: a result held on to holds no buffer
    with pytest.raises(ValueError, match="carries no replay buffer"):
        save_run(plain, tmp_path / "plain", replay=True)
    first = train(tiny(), keep_replay=True)
    out = save_run(first, tmp_path / "run", replay=True)
    assert sorted(p.name for p in out.iterdir()) == sorted((*RUN_FILES, REPLAY_FILE))
    saved = load_replay(out / REPLAY_FILE)
    assert saved["rows"]["obs"].shape[:2] == (first.replay.size // 32, 32)
    # learning_start above what one run collects: only the loaded transitions let the next run learn at once
    config = tiny(init_from=str(out), init_replay=True,
                  overrides={**tiny().overrides, "algo.learning_start": first.replay.size + 1})
    spec = resolve(config)
    assert spec.init.replay == str((out / REPLAY_FILE).resolve())
    assert RunSpec.from_dict(spec.to_dict()).init == spec.init
    went_on = train(spec, keep_replay=True)
    assert went_on.replay.size == first.replay.size + went_on.env_steps
    assert torch.equal(went_on.replay.obs[: first.replay.size // 32], first.replay.obs[: first.replay.size // 32])
    # 256 loaded + 32 collected reach learning_start 257 after the first of its 8 vector steps: 7 x 2 updates (an
    # empty replay would reach it never), on top of the loaded learner's count
    assert went_on.learner.num_updates == first.learner.num_updates + 7 * 2
    save_run(first, out)  # no replay this time: the folder must not keep the earlier one
    assert not (out / REPLAY_FILE).exists()


def test_init_replay_needs_a_source_with_a_replay(tmp_path):
    with pytest.raises(ValueError, match="init_replay needs init_from"):
        resolve(tiny(init_replay=True))
    out = save_run(train(tiny()), tmp_path / "run")
    with pytest.raises(FileNotFoundError, match=f"no {REPLAY_FILE} in .*--save-replay"):
        resolve(tiny(init_from=str(out), init_replay=True))
