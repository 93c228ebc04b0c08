import os

import pytest
from omegaconf import OmegaConf

os.environ.setdefault("RL_WARNINGS", "False")


@pytest.fixture
def cfg():
    """The default config (as Hydra would compose it without overrides)."""
    from bfc.config import Config

    return OmegaConf.structured(Config)
