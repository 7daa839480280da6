"""Every command-line tool's ``--help`` ends with an example and states the unit of every number.

The project rule: "every ``--help`` ends with an example; every numeric option states its unit".
The tools are found, not listed: every module under ``analysis/`` (recursively) and ``geometry/``
that defines ``def main(argv``. Each one's ``main(["--help"])`` runs in-process (no subprocess,
each module imported once) and must

* exit with code 0, printing the help on stdout;
* end with a paragraph that starts with ``example`` and holds a command line
  (``python -m ...`` or ``make ...``);
* state a unit in brackets (``[Hz]``, ``[s]``, ``[-]``, ``[seeds]``, ...) in the help of every
  option whose argparse ``type`` is ``int`` or ``float`` - sub-commands' options included.

The parser is caught by wrapping ``argparse.ArgumentParser.parse_args``; should ``--help`` ever
not stop the tool, the wrapper stops it there (so no twin run or study starts from this test).
"""
import argparse
import importlib
import re
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("analysis", "geometry")
MAIN = re.compile(r"^def main\(argv", re.M)


def cli_modules():
    """Dotted names of the modules under PACKAGES that define ``def main(argv``."""
    names = []
    for pkg in PACKAGES:
        for path in sorted((REPO / pkg).rglob("*.py")):
            if MAIN.search(path.read_text(encoding="utf-8")):
                names.append(".".join(path.relative_to(REPO).with_suffix("").parts))
    return names


MODULES = cli_modules()


class HelpDidNotExit(Exception):
    """parse_args returned although ``--help`` was given."""


def _all_actions(parser, seen=None):
    """(parser prog, action) for every action of ``parser`` and of its sub-command parsers."""
    seen = set() if seen is None else seen
    if id(parser) in seen:
        return
    seen.add(id(parser))
    for action in parser._actions:
        yield parser.prog, action
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                yield from _all_actions(sub, seen)


def run_help(name, monkeypatch, capsys, tmp_path):
    """Import ``name``, call its ``main(["--help"])``; return (exit code, stdout, parsers)."""
    mod = importlib.import_module(name)
    source = Path(mod.__file__).read_text(encoding="utf-8")
    assert "ArgumentParser" in source, (
        "%s.main has no argparse parser: '--help' would run the tool" % name)
    parsers = []
    real_parse_args = argparse.ArgumentParser.parse_args

    def recording_parse_args(self, args=None, namespace=None):
        parsers.append(self)
        real_parse_args(self, args, namespace)
        raise HelpDidNotExit("%s: parse_args(%r) returned" % (name, args))

    def no_subprocess(*a, **k):
        raise AssertionError("%s --help started a subprocess: %r" % (name, a[:1]))

    monkeypatch.setattr(argparse.ArgumentParser, "parse_args", recording_parse_args)
    monkeypatch.setattr(subprocess, "Popen", no_subprocess)
    monkeypatch.setattr(subprocess, "run", no_subprocess)
    monkeypatch.setenv("COLUMNS", "100")
    monkeypatch.chdir(tmp_path)
    capsys.readouterr()
    with pytest.raises(SystemExit) as stop:
        mod.main(["--help"])
    out = capsys.readouterr().out
    return stop.value.code, out, parsers


def test_the_tools_are_found():
    # a sanity floor: the discovery did not silently find nothing
    for name in ("analysis.calibrate", "analysis.sweep", "analysis.bench.dem",
                 "analysis.studies.facet_convergence", "geometry.jar"):
        assert name in MODULES, name


@pytest.mark.parametrize("name", MODULES)
def test_help_ends_with_an_example_and_states_units(name, monkeypatch, capsys, tmp_path):
    code, out, parsers = run_help(name, monkeypatch, capsys, tmp_path)
    assert code == 0, (name, code)
    assert out.strip(), "%s --help printed nothing on stdout" % name
    assert parsers, "%s --help did not go through argparse" % name

    # the last paragraph (block of non-empty lines) is the example
    last = out.strip().split("\n\n")[-1]
    first_line = last.lstrip().splitlines()[0]
    assert first_line.lower().startswith("example"), (
        "%s --help does not end with an example; its last paragraph is:\n%s" % (name, last))
    assert "python -m" in last or "make " in last, (
        "%s --help's example holds no command line ('python -m' or 'make '):\n%s" % (name, last))

    # every int / float option states its unit in brackets
    unitless = []
    top = parsers[0]
    for prog, action in _all_actions(top):
        if action.type in (int, float) and "[" not in (action.help or ""):
            where = "" if prog == top.prog else "(sub-command %s) " % prog
            unitless.append("%s%s (type %s): help %r" % (
                where, "/".join(action.option_strings) or action.dest, action.type.__name__,
                action.help))
    assert not unitless, ("%s: numeric options without a [unit] in their help:\n  "
                          % name) + "\n  ".join(unitless)
