"""One episode per env slot with a deterministic policy, recorded, and its animated picture: what
``flashnav render`` draws (:func:`flashnav.policy_cli.run_render`; the still picture is
:func:`flashnav.viz.draw_trajectories`)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import torch

#: frames in the GIF at most (one every few control steps): keeps the file small
GIF_MAX_FRAMES = 40
#: longest side of the GIF, pixels
GIF_SIZE = 320
GIF_FRAME_MS = 100
AGENT_RGB = (148, 103, 189)  # moving agents in the GIF (matplotlib's tab:purple, as in the PNG)


@torch.no_grad()
def rollout(policy, env, seed: int, shield=None) -> dict:
    """One episode per env slot with the deterministic ``policy`` (behind ``shield``, a
    :class:`flashnav.shield.PeopleShield`, if given: then also ``took_over`` [T, N] bool, the steps on which it
    took over from the policy, rows past an episode's end False).

    Returns ``poses [T+1, N, 3]`` (x, y m, yaw rad; rows past an episode's end repeat its last pose),
    ``length [N]`` (valid rows per slot), ``goals [N, 2]`` m and ``outcomes`` (success / collision /
    timeout); with moving agents also ``agents`` [T+1, N, K, 2] (their centres, m), ``agent_active``
    [T+1, N, K] and ``agent_radius`` [N, K] (rows past an episode's end repeat its last row). The poses are the
    step's ``info["final_pose"]``: the env has already reset a finished slot when ``step`` returns, but the
    picture should end where the robot did.
    """
    preset = env.preset
    obs, _ = env.reset(seed=seed)
    n = env.num_envs
    goals = env.goal.cpu().numpy().copy()
    poses = [env.pose.cpu().numpy().copy()]
    length = np.ones(n, dtype=np.int64)
    running = np.ones(n, dtype=bool)
    outcomes = ["timeout"] * n
    track = env.agents is not None
    if track:
        agents, agent_active = [env.agents.pos.cpu().numpy().copy()], [env.agents.active.cpu().numpy().copy()]
        agent_radius = env.agents.radius.cpu().numpy().copy()
    guard = None
    if shield is not None:
        from flashnav.shield import SimShield

        guard, took_over, every = SimShield(env, shield), [], torch.arange(n, device=env.device)
    for _ in range(preset.episode.horizon):
        action = policy(obs)
        if guard is not None:
            action = guard(every, action)
            took_over.append(guard.took_over.cpu().numpy() & running)
        obs, _, terminated, truncated, info = env.step(action)
        pose = np.where(running[:, None], info["final_pose"].cpu().numpy(), poses[-1])
        poses.append(pose)
        if track:  # a finished slot's agents were re-sampled by the reset: keep its last row
            agents.append(np.where(running[:, None, None], env.agents.pos.cpu().numpy(), agents[-1]))
            agent_active.append(np.where(running[:, None], env.agents.active.cpu().numpy(), agent_active[-1]))
        length += running
        done = (terminated | truncated).cpu().numpy()
        success, collision = info["success"].cpu().numpy(), info["collision"].cpu().numpy()
        for i in np.nonzero(running & done)[0]:
            outcomes[i] = "success" if success[i] else "collision" if collision[i] else "timeout"
        running &= ~done
        if guard is not None:  # the env restarted the finished slots
            guard.forget(torch.as_tensor(done, device=env.device))
        if not running.any():
            break
    out = {"poses": np.stack(poses), "length": length, "goals": goals, "outcomes": outcomes}
    if track:
        out.update(agents=np.stack(agents), agent_active=np.stack(agent_active), agent_radius=agent_radius)
    if guard is not None:
        out["took_over"] = np.stack(took_over)
    return out


def took_over_points(result: dict) -> np.ndarray:
    """[P, 2] m: where the robots stood on the steps a shield took over (:func:`rollout` ``shield=``); empty
    without a shield."""
    if "took_over" not in result:
        return np.zeros((0, 2))
    steps, slots = np.nonzero(result["took_over"])
    return result["poses"][steps, slots, :2]


def agent_tracks(result: dict) -> list[tuple[np.ndarray, float]]:
    """Each agent's track while its episode ran and it was present: ([T', 2] m, radius m); empty
    without agents."""
    if "agents" not in result:
        return []
    tracks = []
    pos, on, radius = result["agents"], result["agent_active"], result["agent_radius"]
    for i, steps in enumerate(result["length"]):
        for j in range(pos.shape[2]):
            rows = on[:steps, i, j]
            if rows.any():
                tracks.append((pos[:steps, i, j][rows], float(radius[i, j])))
    return tracks


def write_gif(grid, result: dict, radius: float, out: str | Path) -> Path:
    """Animated GIF of the rollout: map, paths so far (blue while running, outcome colour after),
    robots as footprint-sized circles with a heading tick (black while a people shield is in charge: the
    rollout's ``took_over``), goals as crosses. Pillow only (matplotlib per frame would be ~50x slower);
    palette mode and <= GIF_MAX_FRAMES frames keep it small."""
    from matplotlib.colors import to_rgb
    from PIL import Image, ImageDraw

    from flashnav.viz import OUTCOME_COLOURS

    rgb = {k: tuple(int(255 * c) for c in to_rgb(v)) for k, v in OUTCOME_COLOURS.items()}
    occ = np.flipud(grid.occupied)  # row 0 is the lowest y; image row 0 is the top
    base = Image.fromarray(np.where(occ, 70, 255).astype(np.uint8)).convert("RGB")
    scale = GIF_SIZE / max(base.size)
    base = base.resize((max(1, round(base.width * scale)), max(1, round(base.height * scale))), Image.NEAREST)
    xmin, ymin, xmax, ymax = grid.bounds
    sx, sy = base.width / (xmax - xmin), base.height / (ymax - ymin)

    def px(x, y):
        return (x - xmin) * sx, base.height - (y - ymin) * sy

    poses, length, goals, outcomes = result["poses"], result["length"], result["goals"], result["outcomes"]
    steps = int(length.max())
    stride = max(1, math.ceil(steps / GIF_MAX_FRAMES))
    ticks = list(range(0, steps, stride))
    if ticks[-1] != steps - 1:
        ticks.append(steps - 1)  # always show the final state
    r = max(2.0, radius * sx)
    frames = []
    for t in ticks:
        frame = base.copy()
        draw = ImageDraw.Draw(frame)
        for i in range(poses.shape[1]):
            end = min(t, int(length[i]) - 1)
            colour = rgb[outcomes[i]] if t >= length[i] - 1 else rgb["running"]
            gx, gy = px(*goals[i])
            draw.line([(gx - 3, gy - 3), (gx + 3, gy + 3)], fill=colour, width=2)
            draw.line([(gx - 3, gy + 3), (gx + 3, gy - 3)], fill=colour, width=2)
            if end > 0:
                draw.line([px(*p) for p in poses[: end + 1, i, :2]], fill=colour, width=1)
            x, y, yaw = poses[end, i]
            cx, cy = px(x, y)
            shielded = "took_over" in result and end < len(result["took_over"]) and result["took_over"][end, i]
            body = (0, 0, 0) if shielded else colour
            draw.ellipse([cx - r, cy - r, cx + r, cy + r], outline=body, width=2)
            draw.line([(cx, cy), (cx + r * math.cos(yaw), cy - r * math.sin(yaw))], fill=body, width=2)
            if "agents" in result:  # the slot's agents: their tracks so far, their discs now
                for j in range(result["agents"].shape[2]):
                    on = result["agent_active"][: end + 1, i, j]
                    if not on[-1]:
                        continue
                    track = [px(*p) for p in result["agents"][: end + 1, i, j][on]]
                    if len(track) > 1:
                        draw.line(track, fill=AGENT_RGB, width=1)
                    ax, ay = track[-1]
                    ar = max(2.0, float(result["agent_radius"][i, j]) * sx)
                    draw.ellipse([ax - ar, ay - ar, ax + ar, ay + ar], fill=AGENT_RGB)
        frames.append(frame.convert("P", palette=Image.ADAPTIVE, colors=32))
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    frames[0].save(out, save_all=True, append_images=frames[1:], duration=GIF_FRAME_MS, loop=0, optimize=True)
    return out
