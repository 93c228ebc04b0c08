"""bfc's one reach into Hydra's internals (bfc/hydra_compat.py): the composition it skips would
answer None for every config the repository can compose, and an override of `hydra.mode` still
gets Hydra's own answer."""

from pathlib import Path

import hydra
import pytest
from hydra import initialize_config_dir
from hydra._internal.hydra import Hydra
from hydra.core.global_hydra import GlobalHydra
from hydra.types import RunMode

import bfc.config  # noqa: F401  (registers the schemas the configs compose with)
from bfc.hydra_compat import HYDRA_VERSIONS, sets_mode, skip_mode_probe

pytestmark = pytest.mark.filterwarnings(r"ignore:\s*.hydra/launcher/ray. is validated against ConfigStore schema")

CONF = Path(__file__).resolve().parents[1] / "conf"


def options(group: str) -> list[str]:
    return sorted(p.stem for p in (CONF / group).glob("*.yaml"))


# one override per option the command line can select (ablations and presets are added with +)
SELECTIONS = [
    [],
    *([f"+ablation={o}"] for o in options("ablation")),
    *([f"+preset={o}"] for o in options("preset")),
    *([f"algo={o}"] for o in options("algo")),
    *([f"extras={o}"] for o in options("extras")),
    *([f"reward={o}"] for o in options("reward")),
    *([f"env/airframe={o}"] for o in options("env/airframe")),
    ["hydra/launcher=joblib"],
    ["hydra/launcher=ray"],
]


@pytest.fixture
def main_hydra(monkeypatch):
    """Hydra's object for conf/, and Hydra.get_mode as it is without bfc's patch."""
    monkeypatch.setattr(Hydra, "get_mode", getattr(Hydra.get_mode, "__wrapped__", Hydra.get_mode))
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        yield GlobalHydra.instance().hydra


def test_the_hydra_version_is_the_one_the_reach_was_written_for():
    assert hydra.__version__.startswith(HYDRA_VERSIONS), hydra.__version__


@pytest.mark.parametrize("overrides", SELECTIONS, ids=lambda o: " ".join(o) or "defaults")
def test_hydras_mode_probe_answers_none_for_every_repository_config(main_hydra, overrides):
    for name in ("config", *(["evaluate"] if not overrides else [])):
        # what get_mode composes (it answers None for a composition that fails too: this must not)
        cfg = main_hydra.compose_config(
            config_name=name,
            overrides=overrides,
            with_log_configuration=False,
            run_mode=RunMode.MULTIRUN,
            validate_sweep_overrides=False,
        )
        assert cfg.hydra.mode is None
        assert main_hydra.get_mode(config_name=name, overrides=overrides) is None


def test_the_patched_probe_answers_none_without_composing(main_hydra, monkeypatch):
    skip_mode_probe()
    skip_mode_probe()  # twice: wraps once
    assert Hydra.get_mode.__wrapped__.__name__ == "get_mode"
    assert not getattr(Hydra.get_mode.__wrapped__, "probe_skipped", False)

    def no_composition(*args, **kwargs):
        raise AssertionError("composed")

    monkeypatch.setattr(Hydra, "compose_config", no_composition)
    assert main_hydra.get_mode(config_name="config", overrides=["+preset=paper", "seed=1"]) is None


@pytest.mark.parametrize("override", ["hydra.mode=MULTIRUN", "++hydra.mode=MULTIRUN"])
def test_an_override_of_hydra_mode_gets_hydras_own_answer(main_hydra, override):
    skip_mode_probe()
    assert main_hydra.get_mode(config_name="config", overrides=["seed=1", override]) == RunMode.MULTIRUN


def test_which_overrides_set_the_mode():
    assert sets_mode(["seed=0", "hydra.mode=RUN"]) and sets_mode(["~hydra.mode"])
    assert not sets_mode(["seed=0", "hydra.run.dir=x", "hydra.job.name=mode"])
