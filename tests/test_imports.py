"""bfc.imports: a package hidden for one import only; the garbage collector held while a launch imports."""

import gc
import importlib.util
import sys

import pytest

from bfc.imports import hold_garbage_collection, release_garbage_collection, without


def test_a_hidden_package_is_not_found_inside_and_imports_after():
    assert "json.tool" not in sys.modules or pytest.skip("json.tool loaded already")
    with without("json.tool"):
        assert importlib.util.find_spec("json.tool") is None
        with pytest.raises(ImportError):
            import json.tool  # noqa: F401
    import json.tool  # noqa: F401,F811

    assert sys.modules["json.tool"].__name__ == "json.tool"


def test_a_package_loaded_already_is_left_alone():
    import json

    with without("json"):
        assert sys.modules["json"] is json
    assert sys.modules["json"] is json


def test_the_package_is_put_back_when_the_import_fails():
    with pytest.raises(RuntimeError), without("json.tool"):
        raise RuntimeError("the import failed")
    assert sys.modules.get("json.tool", "absent") is not None


@pytest.fixture
def garbage_collection():
    """The test process's collector as it was, whatever the test does to it."""
    enabled, frozen = gc.isenabled(), gc.get_freeze_count()
    yield
    if gc.get_freeze_count() > frozen:
        gc.unfreeze()
    (gc.enable if enabled else gc.disable)()


def test_the_held_collector_comes_back_with_the_imports_frozen_out_of_its_sight(garbage_collection):
    hold_garbage_collection()
    assert not gc.isenabled()
    made = [[i] for i in range(1000)]  # what start-up makes
    release_garbage_collection()
    assert gc.isenabled() and gc.get_freeze_count() >= len(made)


def test_releasing_a_collector_never_held_changes_nothing(garbage_collection):
    gc.enable()
    frozen = gc.get_freeze_count()
    release_garbage_collection()
    assert gc.isenabled() and gc.get_freeze_count() == frozen


def test_a_sweep_turns_the_collector_back_on_as_it_starts(garbage_collection):
    from bfc.sweeps import SweepReport

    hold_garbage_collection()
    SweepReport().on_multirun_start(config=None)
    assert gc.isenabled()
