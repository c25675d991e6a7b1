"""RoboMorph: in-context meta-learning of robot dynamics."""

__version__ = "0.1.0"


def __getattr__(name: str):
    # Lazy: `import robomorph` stays light (no torch) for the simulation-only CLIs.
    if name == "Predictor":
        from robomorph.predictor import Predictor

        return Predictor
    raise AttributeError(f"module 'robomorph' has no attribute {name!r}")
