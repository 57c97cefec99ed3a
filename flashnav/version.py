"""FlashNav's version, in a module of its own: modules that record it (checkpoints) import it from
here rather than from the package, whose ``__init__`` reaches the training loop (no import cycle)."""

__version__ = "0.1.0"
