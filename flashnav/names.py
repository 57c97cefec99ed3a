"""The names users choose from, defined once."""

from __future__ import annotations

#: Robot presets shipped in ``flashnav/presets/<name>.yaml``.
ROBOTS = ("turtlebot2", "go2")
#: Learners, each a module of functions in ``flashnav/learn/<name>.py``.
ALGORITHMS = ("fastdsac", "fastsac", "fasttd3")
#: Hyperparameter recipes in ``flashnav/presets/<algorithm>.yaml``.
RECIPES = ("paper", "cpu")
