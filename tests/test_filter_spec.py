"""The filters' declarations (issue 40 item 1): each parameter declared once, and everything derived from it -
the command line's options and checks, ``metrics roc``'s sweeps, the README's table, the API's signature - agrees
with the declarations and with what the filters do."""

from __future__ import annotations

import inspect
import re
from pathlib import Path

import numpy as np
import pytest

import evtools
from evtools.filters import BY_NAME, METHODS, PRESETS, REGISTRY, BAFilter, BAFilterError
from evtools.filters.registry import markdown_table, parameters
from tests.helpers import run

ROOT = Path(__file__).resolve().parents[1]


def test_every_default_is_declared_and_every_declaration_has_a_default():
    for f in REGISTRY:
        declared = [param.name for param in f.params]
        assert len(set(declared)) == len(declared), f.name
        assert set(f.defaults) <= set(PRESETS) and "evtools" in f.defaults, f.name
        assert set(f.defaults["evtools"]) == set(declared), f.name
        for preset, values in f.defaults.items():
            assert set(values) <= set(declared), (f.name, preset)
            BAFilter(16, 12, f.name, preset=preset)  # every preset's defaults pass the filter's own checks


def test_one_name_is_one_kind_and_one_option():
    for name, uses in parameters().items():
        assert len({(param.kind, param.option, param.cli) for _, param in uses}) == 1, name


def test_bounds_are_enforced_as_declared():
    for f in REGISTRY:
        for param in f.params:
            if param.kind not in ("int", "time_us"):
                continue
            with pytest.raises(BAFilterError, match=param.name):
                BAFilter(16, 12, f.name, **{param.name: int(param.low or 1) - 1})
            high = param.high(f.defaults["evtools"]) if callable(param.high) else param.high
            if high is not None:
                with pytest.raises(BAFilterError, match=param.name):
                    BAFilter(16, 12, f.name, **{param.name: int(high) + 1})
                BAFilter(16, 12, f.name, **{param.name: int(high)})


def test_the_command_line_has_one_option_per_parameter_documented_with_every_default():
    from click.testing import CliRunner

    from evtools.cli.bafilter import bafilter

    help_text = CliRunner().invoke(bafilter, ["--help"], terminal_width=400).output
    for name, uses in parameters().items():
        option = uses[0][1].option
        if uses[0][1].cli:
            assert option in help_text, option
            for f, _ in uses:
                assert f"{f.name}" in help_text
        else:
            assert option not in help_text
    assert ", ".join(METHODS) in help_text


def test_an_option_that_applies_to_no_stage_is_a_usage_error(tmp_path):
    source = ROOT / "samples" / "step.aedat4"
    for method, option, value in (("baf", "--k", "3"), ("ynoise", "--window", "4"), ("dwf", "--dt-us", "5ms"),
                                  ("stcf", "--hot-ratio", "3")):
        result = run("bafilter", source, "--method", method, option, value, "-o", tmp_path / "x.aedat4", check=False)
        assert result.returncode == 2 and f"{option} do(es) not apply to --method {method}" in result.stderr.decode()
        assert not (tmp_path / "x.aedat4").exists()


def test_the_new_filter_runs_from_the_command_line_as_from_python(tmp_path):
    """ynoise, added with a kernel, a module, a naive reference and a registry line, is a command-line filter."""
    source = ROOT / "samples" / "flicker.aedat4"
    out = tmp_path / "y.aedat4"
    run("bafilter", source, "--method", "ynoise", "--k", "3", "--dt-us", "20ms", "-o", out)
    events, info = evtools.read(source)
    expected = evtools.bafilter(events, info, "ynoise", k=3, dt_us=20_000)
    assert 0 < len(expected) < len(events)
    assert np.array_equal(evtools.read(out)[0], expected)


def test_sweepable_parameters_come_from_the_declarations():
    from evtools.cli.metrics_denoise import SWEEPABLE

    expected = {name.replace("_", "-") for name, uses in parameters().items()
                if uses[0][1].sweepable and uses[0][1].cli}
    assert set(SWEEPABLE) == expected and {"dt-us", "k", "threshold", "hot-ratio"} <= expected


def test_the_readme_table_is_the_declarations():
    assert markdown_table() in (ROOT / "README.md").read_text()
    # the command the README names prints it, and nothing else (`-m evtools.filters.registry` drew runpy's warning)
    import subprocess
    import sys

    printed = subprocess.run([sys.executable, "-m", "evtools.filters"], capture_output=True, text=True, timeout=60)
    assert printed.returncode == 0 and printed.stdout.strip() == markdown_table().strip() and not printed.stderr


def test_the_api_signature_lists_every_parameter_and_its_docs_name_only_methods_that_exist():
    signature = inspect.signature(evtools.bafilter)
    assert set(parameters()) <= set(signature.parameters)
    assert all(signature.parameters[name].kind == inspect.Parameter.KEYWORD_ONLY for name in parameters())
    for function in (evtools.bafilter, evtools.filters.ba_filter, BAFilter):
        documented = function.__doc__
        for name in parameters():
            assert f"{name} : " in documented, (function, name)
    section = evtools.bafilter.__doc__.split("method : str")[1].split("preset :")[0]
    named = set(re.findall(r"``(\w+)``", section))
    assert named == set(METHODS), named ^ set(METHODS)


def test_a_filter_name_is_a_module_and_a_registry_line():
    for f in REGISTRY:
        assert BY_NAME[f.name] is f
        assert f.__module__.startswith("evtools.filters.") and f.keeps and f.params
