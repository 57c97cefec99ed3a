"""FlashNav: train deployable 2D-LiDAR robot-navigation policies in seconds."""

__version__ = "0.1.0"


def make_env(*args, **kwargs):
    """Batched navigation environment; see :func:`flashnav.sim.env.make_env`."""
    from flashnav.sim.env import make_env as _make_env

    return _make_env(*args, **kwargs)


def train(*args, **kwargs):
    """Train a policy; see :func:`flashnav.learn.loop.train`."""
    from flashnav.learn.loop import train as _train

    return _train(*args, **kwargs)
