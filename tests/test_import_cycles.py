"""No import cycle between the project's modules, type-only and function-level imports included."""

from __future__ import annotations

from scripts.check_imports import cycles, import_graph, module_files


def test_the_shipped_packages_have_no_import_cycle():
    graph = import_graph(module_files())
    assert "pghm.splat.spec" in graph["pghm.gl.resources"]  # the graph sees the project's imports
    assert cycles(graph) == []


def test_a_cycle_through_type_checking_and_a_function_body_is_found(tmp_path):
    package = tmp_path / "pghm"
    package.mkdir()
    (package / "__init__.py").write_text("")
    (package / "a.py").write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from pghm.b import B\n")
    (package / "b.py").write_text("def f():\n    from . import a\n    return a\n")
    (package / "c.py").write_text("from pghm import b\n")

    assert cycles(import_graph(module_files(tmp_path))) == [["pghm.a", "pghm.b"]]
