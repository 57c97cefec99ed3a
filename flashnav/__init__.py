"""FlashNav: train deployable 2D-LiDAR robot-navigation policies in seconds."""

from flashnav.version import __version__  # noqa: F401 (the package's version)


def make_env(*args, **kwargs):
    """Batched navigation environment; see :func:`flashnav.sim.env.make_env`."""
    from flashnav.sim.env import make_env as _make_env

    return _make_env(*args, **kwargs)


def train(*args, **kwargs):
    """Train a policy; see :func:`flashnav.learn.loop.train`."""
    from flashnav.learn.loop import train as _train

    return _train(*args, **kwargs)


def _register() -> None:
    """Register the Gymnasium ids (strings only: nothing heavy is imported until an env is made)."""
    import gymnasium

    for env_id, robot in {"flashnav/TurtleBot2-v0": "turtlebot2", "flashnav/Go2-v0": "go2"}.items():
        if env_id not in gymnasium.registry:
            gymnasium.register(
                id=env_id,
                entry_point="flashnav.sim.gym_env:NavEnv",
                vector_entry_point="flashnav.sim.gym_env:make_vec_env",
                kwargs={"robot": robot},
            )


_register()
