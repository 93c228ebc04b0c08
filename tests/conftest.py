import os

import pytest

os.environ.setdefault("RL_WARNINGS", "False")


@pytest.fixture
def cfg():
    """The paper's BFC (`extras=none`: no randomisation, no integral, the paper's JD starts), as
    Hydra composes it: the plain world most unit tests reason about. `python train.py`'s own
    default (the robust extras on) is `bfc.config.compose([])`."""
    from bfc.config import compose

    return compose(["extras=none"])
