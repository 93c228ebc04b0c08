"""The house's rules, checked: the import contracts of pyproject.toml and no import cycle anywhere."""

import shutil
import subprocess
import sys
from pathlib import Path

import grimp

ROOT = Path(__file__).resolve().parents[1]


def test_the_import_contracts_hold():
    """`lint-imports` (import-linter, the dev extra): the layers, and training never reaching the
    classical controllers, directly or through another module."""
    command = shutil.which("lint-imports", path=str(Path(sys.executable).parent)) or "lint-imports"
    r = subprocess.run([command, "--no-cache"], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-1000:]
    assert "3 kept, 0 broken" in r.stdout


def test_no_module_of_bfc_is_part_of_an_import_cycle():
    graph = grimp.build_graph("bfc", cache_dir=None)
    cycles = []
    for module in sorted(graph.modules):
        for imported in graph.find_modules_directly_imported_by(module):
            if imported != module and graph.chain_exists(importer=imported, imported=module):
                cycles.append(" -> ".join(graph.find_shortest_chain(importer=imported, imported=module)))
    assert not cycles, cycles
