"""The documentation's generated pages: the config-key reference holds every key of every study with its
help, and the API page every public name (the Sphinx build itself runs in `make test`, after pytest)."""
import importlib.util
import inspect
import re
from pathlib import Path

import pytest

from nlosbench import studies
from nlosbench.experiment.config import TOP, study_schema
from nlosbench.schema import describe

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("nlosbench_docs", ROOT / "docs" / "_ext" / "nlosbench_docs.py")
docs_ext = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(docs_ext)


def table_rows(page: str, heading: str) -> dict[str, list[str]]:
    """key path → cells of the Markdown table under `## heading`."""
    section = page.split(f"## {heading}\n", 1)[1].split("\n## ", 1)[0]
    rows = [ln for ln in section.splitlines() if ln.startswith("| `")]
    cells = [[c.strip() for c in re.split(r"(?<!\\)\|", ln)[1:-1]] for ln in rows]
    return {c[0].strip("`"): c for c in cells}


@pytest.mark.parametrize("study", studies.available())
def test_the_config_reference_has_every_key_of_every_study_with_its_help(study):
    rows = table_rows(docs_ext.config_page(), f"`type: {study}`")
    keys = describe(study_schema(studies.get(study)))
    assert list(rows) == [k.path for k in keys]
    for k in keys:
        help_cell = rows[k.path][3].replace("\\|", "|").replace("\\*", "*").replace("&lt;", "<")
        assert help_cell == " ".join(k.help.split()), k.path


def test_the_config_reference_has_the_top_level_keys():
    rows = table_rows(docs_ext.config_page(), "Top level")
    assert list(rows) == [k.path for k in describe(TOP)]
    assert rows["executor.type"][1] == "string: one of local, serial, dask" and rows["seed"][2] == "`0`"


def test_the_api_page_lists_every_public_name():
    page = docs_ext.api_page()
    import nlosbench

    listed = set(re.findall(r"^   (\w+)$", page, re.M))
    public = {n for n in nlosbench.__all__ if not inspect.ismodule(getattr(nlosbench, n))}
    assert public and public <= listed
    for module in ("nlosbench.bounds", "nlosbench.estimators", "nlosbench.noise"):
        assert f".. currentmodule:: {module}" in page


def test_the_guides_python_tour_runs_and_finds_the_ball():
    """docs/guide/python.md's example, as a reader runs it (cornell_ball, CPU renders are bit-reproducible)."""
    import math

    from nlosbench.estimators.base import STATUSES

    page = (ROOT / "docs" / "guide" / "python.md").read_text()
    scope: dict = {}
    exec(compile(re.search(r"```python\n(.*?)```", page, re.S).group(1), "python.md", "exec"), scope)
    p, fit, bank = scope["p"], scope["fit"], scope["bank"]
    assert abs(float(p.theta[0]) - 0.1) < 1e-12 and bank.renders >= 3 * 13  # "θ* = 0.1 m", "3 × 13 renders"
    hcr, crlb = p.bounds["hcr"], p.bounds["crlb"]
    assert hcr.log10 <= hcr.upper and crlb.lower <= crlb.log10 <= crlb.upper
    assert "grid-limited" in scope["curve"].zzb[0].flags  # as the comment says
    assert fit.status in STATUSES and fit.renders > 0
    # one observation: the fit lands within 5 standard deviations the CRLB allows (seeded, so deterministic)
    assert abs(float(fit.theta[0]) - 0.1) < 5 * math.sqrt(10 ** crlb.upper)


def test_the_layout_page_names_every_module_of_the_package():
    """docs/developers/layout.md lists the package's modules; a module added without a line there fails."""
    page = (ROOT / "docs" / "developers" / "layout.md").read_text()
    package = ROOT / "nlosbench"
    modules = {p.stem for p in package.rglob("*.py") if not p.stem.startswith("__")}
    modules |= {p.name for p in package.iterdir() if p.is_dir() and (p / "__init__.py").is_file()}
    missing = sorted(m for m in modules if not re.search(rf"(?<![\w-]){re.escape(m)}(?![\w-])", page))
    assert not missing, missing


def test_the_cost_table_has_a_row_per_config_with_its_estimate_rate_and_committed_run():
    """performance.md's cost table (generated at every build): a row per configs/*.yaml with the plan `nlosbench run`
    prints, every config with a measured rate, and a committed run's wall time from its machine.json."""
    import json

    from nlosbench.experiment.runner import forecast
    from nlosbench.studies.estimate import describe

    page = docs_ext.costs_page()
    rows = {c[0].strip("`"): c for c in (
        [x.strip() for x in ln.split("|")[1:-1]] for ln in page.splitlines() if ln.startswith("| `"))}
    assert list(rows) == sorted(p.name for p in (ROOT / "configs").glob("*.yaml"))
    unrated = [c for c, cells in rows.items() if "no rate measured" in cells[3]]
    assert not unrated, f"no rate in results/rates.json for {unrated}: python scripts/measure_rates.py {unrated[0]}"
    _, studies_ = forecast(ROOT / "configs" / "quick.yaml")
    machine = json.loads((ROOT / "results" / "quick" / "machine.json").read_text())
    quick = rows["quick.yaml"]
    assert quick[1] == str(sum(e.renders for e in studies_.values())) and quick[4] == "`results/quick/`"
    assert quick[5] == describe(machine["seconds_total"])
    assert quick[6] == str(sum(s["renders"] for s in machine["studies"].values()))


def test_an_option_printed_with_an_en_dash_fails_the_build(tmp_path):
    """The build's last check (`build-finished`) finds a command's `--set` or `--out` printed as `–set` (smart
    quotes), in prose or in a code tag, and leaves a dash between numbers, in a name or spaced as prose alone: the
    HTML build of `make test` fails on the first kind."""
    (tmp_path / "cli.html").write_text("<p>nlosbench run c.yaml –set seed=3</p><code>–out runs/x</code>")
    (tmp_path / "prose.html").write_text("<p>Θ = [0.7–1.69] m; Gauss–Newton; two cores – and no GPU; --set</p>")
    hits = docs_ext.option_dashes(tmp_path)
    assert len(hits) == 2 and all(h.startswith("cli.html") for h in hits), hits
