"""fastrl: reinforcement learning on simulated robots, physics and learning in one compiled program."""

__version__ = "0.1.0"
