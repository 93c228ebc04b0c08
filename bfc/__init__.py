"""bfc: the Bio-inspired Flight Controller (Dooraki & Lee, 2020) on a MuJoCo Hummingbird with TorchRL."""

__version__ = "0.1.0"


def make_env(cfg, **overrides):
    """Build the env and the transform stack a config asks for (see bfc.make_env)."""
    from bfc.make_env import make_env as _make_env

    return _make_env(cfg, **overrides)
