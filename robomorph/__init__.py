"""RoboMorph: in-context meta-learning of robot dynamics."""

__version__ = "0.1.0"
