"""bfc.imports.without: a package hidden for one import only."""

import importlib.util
import sys

import pytest

from bfc.imports import without


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
