"""`nlosbench list` (every kind, one section each) and `nlosbench list KIND` (one kind, no heading): a line
for every item, its name and what it is."""
import pytest

from nlosbench import cli, estimators, noise, scenes, studies

KINDS = ["scenes", "estimators", "noise", "studies"]


def expected(kind: str) -> list[str]:
    """What each kind's registry says is available (the names, which start each line)."""
    return {"scenes": scenes.available, "estimators": estimators.available, "noise": noise.available,
            "studies": studies.available}[kind]()


def sections(text: str) -> dict[str, list[str]]:
    """Parse `heading:` lines followed by indented items; blank lines separate sections."""
    out: dict[str, list[str]] = {}
    current = None
    for line in text.splitlines():
        if not line.strip():
            continue
        if line.startswith("  "):
            assert current is not None, f"item before any heading: {line!r}"
            out[current].append(line.strip())
        else:
            assert line.endswith(":") and line[:-1] not in out, f"bad or repeated heading: {line!r}"
            current = line[:-1]
            out[current] = []
    return out


def names(kind: str, lines: list[str]) -> list[str]:
    return [ln.split(":", 1)[0] for ln in lines]


def test_list_without_argument_shows_every_kind_under_a_heading(capsys):
    assert cli.main(["list"]) == 0
    out = sections(capsys.readouterr().out)
    assert list(out) == KINDS
    for kind in KINDS:
        assert expected(kind), f"no {kind} registered: the test would prove nothing"
        assert names(kind, out[kind]) == expected(kind), kind
    # every item carries a one-line description, as `list KIND` prints it
    for kind in KINDS:
        assert all(": " in ln and len(ln.split(": ", 1)[1]) > 20 for ln in out[kind]), out[kind]


@pytest.mark.parametrize("kind", KINDS)
def test_list_one_kind_prints_only_that_kind_without_heading(kind, capsys):
    assert cli.main(["list", kind]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert names(kind, lines) == expected(kind)
    assert f"{kind}:" not in lines


def test_list_sections_match_single_kind_output(capsys):
    cli.main(["list"])
    every = sections(capsys.readouterr().out)
    for kind in KINDS:
        cli.main(["list", kind])
        assert capsys.readouterr().out.splitlines() == every[kind]


def test_list_unknown_kind_is_a_usage_error(capsys):
    with pytest.raises(SystemExit) as e:
        cli.main(["list", "bogus"])
    assert e.value.code == 2
    assert "invalid choice" in capsys.readouterr().err
