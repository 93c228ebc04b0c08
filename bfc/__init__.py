"""bfc: the Bio-inspired Flight Controller (Dooraki & Lee, 2020) on a MuJoCo Hummingbird with TorchRL."""

__version__ = "0.1.0"


def make_env(cfg, **options):
    """Build the env and the transform stack a config asks for (see bfc.factory.make_env).

    A function, never shadowed by a submodule of the same name (there is none), so it can be
    called any number of times in any import order; bfc.factory is imported on first call.
    """
    from bfc.factory import make_env as _make_env

    return _make_env(cfg, **options)
