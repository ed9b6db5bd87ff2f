"""Small CLI promises: the version, help that prints what it says, choices and flags, completion, the
whole-number message, ``forest examples list`` and a reader that goes away early."""

from __future__ import annotations

import re
import subprocess
import sys
import textwrap
import tomllib
from pathlib import Path
from typing import Any

import pytest

from forest import cli

ROOT = Path(__file__).resolve().parents[1]
FOREST = [sys.executable, "-m", "forest.cli"]
MINIMAL = '[terrain]\nflat = {}\n[[species]]\nmodel = "broadleaf"\npercent = 50\n'


def choices(param: Any) -> tuple[str, ...]:
    """The fixed values an option takes (none: empty)."""
    desc = getattr(param, "type_descriptor", None)  # typer's own parameters
    values = desc.choices if desc is not None else getattr(getattr(param, "type", None), "choices", None)
    return tuple(values or ())


def run_main(capsys, *args: str) -> tuple[int, str, str]:
    """``forest args`` in this process: (exit status, stdout, stderr)."""
    with pytest.raises(SystemExit) as e:
        cli.main([str(a) for a in args])
    out = capsys.readouterr()
    return int(e.value.code or 0), out.out, out.err


def commands() -> list[tuple[list[str], Any]]:
    """Every command and group of the CLI with its words (the root is [])."""
    import typer.main

    out, todo = [], [([], typer.main.get_command(cli.app))]
    while todo:
        words, cmd = todo.pop()
        out.append((words, cmd))
        todo += [([*words, name], sub) for name, sub in getattr(cmd, "commands", {}).items()]
    return out


@pytest.fixture(scope="module")
def helps() -> dict[tuple[str, ...], tuple[Any, str]]:
    """Each command's words -> (the click command, its --help text), as a wide terminal would show it."""
    out = {}
    for words, cmd in commands():
        with cmd.make_context(" ".join(["forest", *words]), [], resilient_parsing=True) as c:
            c.max_content_width = c.terminal_width = 200
            out[tuple(words)] = (cmd, cmd.get_help(c))
    return out


# -- the version ---------------------------------------------------------------------------------------------


def test_the_version_is_the_packages(capsys, monkeypatch):
    version = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]
    code, out, _ = run_main(capsys, "--version")
    assert code == 0 and out.strip() == f"forest {version}"
    # Not installed (a source checkout on PYTHONPATH): pyproject.toml's version all the same.
    import importlib.metadata

    import forest

    def not_installed(_name: str) -> str:
        raise importlib.metadata.PackageNotFoundError("forest")

    monkeypatch.setattr(importlib.metadata, "version", not_installed)
    forest.package_version.cache_clear()
    try:
        assert forest.package_version() == version
    finally:
        forest.package_version.cache_clear()


# -- help ----------------------------------------------------------------------------------------------------


def test_square_brackets_in_help_texts_are_printed(helps):
    """``[render] variant`` in a help string is a config section, not markup: --help shows it as written."""
    seen = set()
    for words, (cmd, text) in helps.items():
        flat = " ".join(text.split())
        for p in cmd.params:
            for token in re.findall(r"\[[a-z_.]+\]", getattr(p, "help", None) or ""):
                assert token in flat, f"forest {' '.join(words)} --help lost {token} of {p.opts}"
                seen.add((words, token))
    assert (("render",), "[render]") in seen and (("scatter",), "[scatter]") in seen


def test_flags_show_no_value_and_fixed_choices_show_them(helps):
    shown = 0
    for words, (cmd, text) in helps.items():
        assert "<bool>" not in text, f"forest {' '.join(words)} --help"
        for p in cmd.params:
            values = choices(p)
            if values and p.opts[0].startswith("-"):
                assert "|".join(values) in text, (words, p.opts)
                shown += 1
    assert shown >= 8  # --progress, render and match --variant, --mode, --anchor, --map-prior, --lod, --up, ...


def test_option_choices_are_the_values_forest_knows():
    from forest.library.importer import UNITS
    from forest.lookdev.match import MODES
    from forest.progress import MODES as PROGRESS
    from forest.render.path.frame import JIT_VARIANTS
    from forest.runtime import VARIANTS

    params = {(tuple(w), o): p for w, cmd in commands() for p in cmd.params for o in p.opts}

    def values(words: tuple[str, ...], opt: str) -> tuple[str, ...]:
        return choices(params[(words, opt)])

    assert values((), "--progress") == PROGRESS
    assert values(("render",), "--variant") == VARIANTS
    assert values(("match",), "--variant") == JIT_VARIANTS
    assert values(("match",), "--mode") == MODES
    assert set(values(("library", "add"), "--units")) - {"auto"} <= set(UNITS)


def test_a_value_outside_the_choices_is_one_line_and_exit_2(capsys, tmp_path):
    cfg = tmp_path / "scene.toml"
    cfg.write_text(MINIMAL)
    code, _, err = run_main(capsys, "render", cfg, "-o", tmp_path / "x.exr", "--variant", "metal")
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert err.startswith("forest: error: ") and "--variant" in err and "'metal'" in err and "llvm_ad_rgb" in err
    assert "Value error" not in err and not (tmp_path / "x.exr").exists()


def test_shell_completion_is_offered_and_forest_alone_still_prints_help(helps, capsys):
    root_help = helps[()][1]
    assert "--install-completion" in root_help and "--show-completion" in root_help
    code, out, err = run_main(capsys)
    assert code == 2 and "Usage: forest" in out and "Commands:" in out and "Traceback" not in err


# -- config messages -----------------------------------------------------------------------------------------


def test_a_whole_number_written_with_a_decimal_point_is_told_so():
    from forest.config import parse_config
    from forest.errors import ForestError

    with pytest.raises(ForestError) as e:
        parse_config(MINIMAL + "[render]\nwidth = 64.0\n")
    assert "render.width" in str(e.value) and "without a decimal point" in str(e.value) and "64.0" in str(e.value)
    with pytest.raises(ForestError) as e:
        parse_config(MINIMAL + "[render]\nwidth = 64.5\n")
    assert "whole number" in str(e.value) and "64.5" in str(e.value) and "decimal point" not in str(e.value)


# -- forest examples list ------------------------------------------------------------------------------------


def test_examples_list_prints_whole_descriptions(capsys):
    from forest.example_scenes import example_names

    code, out, _ = run_main(capsys, "examples", "list")
    lines = out.splitlines()
    names = example_names()
    assert code == 0 and [line.split()[0] for line in lines] == names  # one line each off a terminal
    for line in lines:
        assert line.rstrip().endswith((".", ")")), f"cut mid-sentence: {line!r}"


def test_examples_list_wraps_to_the_terminal_width():
    from forest.commands.examples import example_description, listing_entry

    text = example_description("flythrough")
    entry = listing_entry("flythrough", text, 60)
    rows = entry.splitlines()
    assert len(rows) > 1 and all(len(r) <= 60 for r in rows)
    assert rows[0].startswith("flythrough ") and all(r.startswith(" " * 13) for r in rows[1:])
    assert " ".join(entry.split()[1:]) == " ".join(text.split())


@pytest.mark.parametrize(
    ("args", "code"),
    [(["examples", "list"], 0), (["schema"], 0), (["render", "--help"], 0), (["--version"], 0)],
)
def test_a_reader_that_goes_away_is_no_error_for_listings(args, code):
    """``forest examples list | head -1``: the reader leaves before forest writes; a listing still succeeds."""
    p = subprocess.Popen([*FOREST, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=ROOT)
    assert p.stdout is not None and p.stderr is not None
    p.stdout.close()  # nobody reads forest's output any more
    err = p.stderr.read().decode()
    assert p.wait(timeout=120) == code, err
    assert err == ""


def test_the_help_of_every_command_prints(helps):
    """No help text trips the formatter (a stray bracket, a very long choice list)."""
    for words, (_, text) in helps.items():
        assert textwrap.dedent(text).startswith("Usage: forest"), words
