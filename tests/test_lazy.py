"""The lazy module: nothing imported until an attribute is read, a missing library named with its hint."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from ldlmap.core.lazy import LazyModule, MissingDependency, lazy_module

ROOT = Path(__file__).resolve().parents[1]


def test_imports_on_first_attribute_only():
    code = ("import sys; from ldlmap.core.lazy import lazy_module; t = lazy_module('tomllib'); "
            "before = 'tomllib' in sys.modules; v = t.loads('a = 1'); print(before, v['a'], 'tomllib' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True,
                         env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"})
    assert out.stdout.split() == ["False", "1", "True"]


def test_an_imported_module_is_returned_as_is():
    import json

    assert lazy_module("json") is json


def test_missing_library_names_the_hint():
    m = lazy_module("ldl_no_such_library", hint="pip install ldl-no-such-library")
    assert isinstance(m, LazyModule) and not m.loaded
    with pytest.raises(MissingDependency, match="pip install ldl-no-such-library"):
        m.anything


def test_dunder_probes_do_not_import():
    m = lazy_module("ldl_no_such_library_either", hint="x")
    assert not hasattr(m, "__wrapped__")
