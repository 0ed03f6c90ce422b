"""Command-line and packaging conventions: --version, `python -m nlosbench`, help on every argument,
`list keys`, one source for the version, py.typed, a package-index description without relative links."""
import argparse
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

import nlosbench
from nlosbench import cli, studies
from nlosbench.experiment.config import TOP, study_schema
from nlosbench.schema import describe

tomllib = pytest.importorskip("tomllib")  # Python >= 3.11
ROOT = Path(__file__).resolve().parents[1]
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())


def test_python_dash_m_prints_the_version():
    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    proc = subprocess.run([sys.executable, "-m", "nlosbench", "--version"], capture_output=True, text=True,
                          env=env, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == f"nlosbench {nlosbench.__version__}"
    assert re.fullmatch(r"\d+\.\d+\.\d+", nlosbench.__version__)


def test_the_version_is_written_once():
    project = PYPROJECT["project"]
    assert "version" not in project and "version" in project["dynamic"]
    assert PYPROJECT["tool"]["setuptools"]["dynamic"]["version"] == {"attr": "nlosbench.__version__"}


def _actions(parser: argparse.ArgumentParser, where: str = "nlosbench"):
    """(where, action) for every argument of the parser and of its sub-commands."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _actions(sub, f"{where} {name}")
        elif not isinstance(action, argparse._HelpAction):
            yield where, action


def test_every_argument_has_help_text():
    actions = list(_actions(cli.build_parser()))
    assert len(actions) > 20, "too few arguments found: the walk over the parser is broken"
    missing = [f"{where} {a.dest}" for where, a in actions if not (a.help or "").strip()]
    assert not missing, f"arguments without help: {missing}"


def _parsers(parser: argparse.ArgumentParser, where: str = "nlosbench"):
    """(where, parser) for the parser and each of its sub-commands."""
    yield where, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _parsers(sub, f"{where} {name}")


def test_every_command_prints_its_help():
    """argparse expands %-formats in help text only when it prints it: a bare % in a help string breaks --help."""
    parsers = list(_parsers(cli.build_parser()))
    assert len(parsers) > 5
    for where, parser in parsers:
        assert parser.format_help().startswith("usage:"), where


@pytest.mark.parametrize("study", studies.available())
def test_list_keys_prints_every_key_of_a_study_with_its_help(study, capsys):
    assert cli.main(["list", "keys", study]) == 0
    lines = capsys.readouterr().out.splitlines()
    rows = describe(study_schema(studies.get(study)))
    assert len(lines) == len(rows) + 1  # a title, then one line per key
    for row, line in zip(rows, lines[1:], strict=True):
        assert line.split()[0] == row.path
        assert line.rstrip().endswith(row.help.rstrip()), (line, row.help)
    assert sum(bool(r.help) for r in rows) >= len(rows) - 2, "most keys have help: does describe() lose it?"


def test_list_keys_without_a_study_prints_the_top_level_keys(capsys):
    assert cli.main(["list", "keys"]) == 0
    paths = [ln.split()[0] for ln in capsys.readouterr().out.splitlines()[1:]]
    assert paths == [r.path for r in describe(TOP)] and "executor.connect_timeout" in paths


def test_list_keys_of_an_unknown_study_is_one_line(capsys):
    assert cli.main(["list", "keys", "bound"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "did you mean 'bounds'?" in err


def test_py_typed_ships_as_package_data():
    assert (ROOT / "nlosbench" / "py.typed").is_file()
    assert "py.typed" in PYPROJECT["tool"]["setuptools"]["package-data"]["nlosbench"]


def test_the_package_index_description_has_no_relative_links():
    readme = PYPROJECT["project"]["readme"]
    text = (ROOT / readme["file"]).read_text()
    links = re.findall(r"\]\(([^)]+)\)", text) + re.findall(r"<img [^>]*src=\"([^\"]+)\"", text)
    assert "](" in text and links, "the link pattern found nothing in a text that has links: it is broken"
    relative = [u for u in links if not re.match(r"https?://", u)]
    assert not relative, relative
    assert len(text.splitlines()) <= 40, "a short description: the README is the landing page"


def test_licence_and_citation():
    assert PYPROJECT["project"]["license"] == "BSD-3-Clause"
    licence = (ROOT / "LICENSE").read_text()
    assert "BSD 3-Clause" in licence and "Copyright (c) 2026, The nlosbench developers" in licence
    import yaml

    cff = yaml.safe_load((ROOT / "CITATION.cff").read_text())
    assert cff["authors"] == [{"name": "The nlosbench developers"}] and cff["version"] == nlosbench.__version__
    paper = cff["references"][0]
    assert [a["family-names"] for a in paper["authors"]] == ["Sambasivan", "Coulter", "Paxman", "Haupt"]
    assert paper["status"] == "preprint" and not {"year", "doi", "journal"} & set(paper)


def test_a_reader_that_stops_reading_is_not_an_error():
    """`nlosbench list | head -1`: the pipe closes before nlosbench has written; exit 0 and nothing on stderr
    (it printed "nlosbench: error: Broken pipe (EPIPE)", exit 1, which fails a `set -o pipefail` script)."""
    r, w = os.pipe()
    os.close(r)  # the reader is gone before the first write: every write is EPIPE
    proc = subprocess.run([sys.executable, "-m", "nlosbench", "list"], stdout=w, stderr=subprocess.PIPE, text=True,
                          cwd=ROOT, timeout=120)
    os.close(w)
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr
