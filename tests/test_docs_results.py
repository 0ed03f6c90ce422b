"""Numbers the documentation quotes from committed runs are read from the runs' files (the `{result}` role,
docs/_ext/nlosbench_results.py), never typed: a changed file changes the page, a missing one fails it, and a
number a run printed that appears as typed text in the pages or the README is an error."""
import csv
import importlib.util
import re
import shutil
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("nlosbench_results", ROOT / "docs" / "_ext" / "nlosbench_results.py")
results_ext = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(results_ext)
resolve, ResultError = results_ext.resolve, results_ext.ResultError

ROLE = re.compile(r"\{result\}`([^`]*)`")
BOUNDS = "quick/00-bounds/bounds.csv"
AT_13 = f"{BOUNDS}[noise_index=0, theta_object_position=1.3]"


def pages() -> list[Path]:
    generated = {"_build", "generated", "_generated"}  # read from the code and the files at every build
    docs = [p for p in sorted((ROOT / "docs").rglob("*.md")) if not generated & set(p.parts)]
    return [p for p in docs if p.name not in ("api.md", "config.md")]


@pytest.fixture
def copied(tmp_path) -> Path:
    """A copy of results/quick/00-bounds, to change."""
    dest = tmp_path / BOUNDS
    dest.parent.mkdir(parents=True)
    shutil.copy(ROOT / "results" / BOUNDS, dest)
    return dest


def _edit(path: Path, fn) -> None:
    with path.open(newline="") as f:
        rows = list(csv.DictReader(f))
    rows = fn(rows)
    with path.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)


def test_a_changed_number_in_the_file_is_the_number_printed(copied):
    root = copied.parents[2]
    before = resolve(f"{AT_13} log10_crlb :.2f", root)
    assert before == resolve(f"{AT_13} log10_crlb :.2f")  # the copy reads as the committed file

    def change(rows):
        for r in rows:
            if r["noise_index"] == "0" and abs(float(r["theta_object_position"]) - 1.3) < 1e-9:
                r["log10_crlb"] = "-2.5"
        return rows

    _edit(copied, change)
    assert resolve(f"{AT_13} log10_crlb :.2f", root) == "−2.50" != before
    assert resolve(f"{AT_13} 1e4 * 10 ** log10_crlb", root) == "31.6"


def test_a_missing_file_row_or_column_is_an_error(copied):
    root = copied.parents[2]
    with pytest.raises(ResultError, match="no such file"):
        resolve("quick/00-bounds/absent.csv[theta_object_position=1.3] log10_crlb", root)
    with pytest.raises(ResultError, match="no row"):
        resolve(f"{BOUNDS}[noise_index=0, theta_object_position=9.9] log10_crlb", root)
    with pytest.raises(ResultError, match="no column"):
        resolve(f"{AT_13} log10_crbl", root)
    with pytest.raises(ResultError, match="rows match"):
        resolve(f"{BOUNDS}[noise_index=0] log10_crlb", root)  # every θ of the grid
    _edit(copied, lambda rows: [{k: v for k, v in r.items() if k != "log10_crlb"} for r in rows])
    with pytest.raises(ResultError, match="no column or key 'log10_crlb'"):
        resolve(f"{AT_13} log10_crlb", root)


def test_the_notation_selectors_and_json():
    assert results_ext.format_number(1.13e-5, ".2g") == "1.1e-5"
    assert results_ext.format_number(-0.0746, ".2g") == "−0.075"
    assert results_ext.format_number(float("inf")) == "∞"
    assert results_ext.format_number(230.4, ".2s") == "230" and results_ext.format_number(0.03, ".2s") == "0.030"
    assert results_ext.format_number(5.06e6, ".2s") == "5.1e6"
    assert results_ext.format_number(862.4, "time") == "14 min 22 s"
    assert resolve(f"{BOUNDS}[noise_index=0, theta_object_position=0.79] theta_object_position :g") == "0.79"
    lo = resolve(f"{BOUNDS}[noise_index=0, theta_object_position>=0.79] min(theta_object_position) :g")
    assert lo == "0.79"  # 0.7899999999999999 in the file: numbers compare as numbers
    assert float(resolve("quick/machine.json seconds_total :.1f")) > 0
    assert int(resolve("quick/machine.json[studies.00-bounds] renders")) > 0
    noise = "quick/results.json[studies.00-bounds.results.noise.AWGN(sigma=0.025)]"  # a key with dots
    assert int(resolve(f"{noise} not_limits")) >= 0
    light = "repro_fidelity/results.json[studies.00-fidelity.results.knobs.prune.points.value=light_c]"
    assert resolve(f"{light} value") == "light_c"  # the list's object that holds the value
    with pytest.raises(ResultError, match="no key"):
        resolve("quick/machine.json[studies.absent] renders")


def test_every_result_role_in_the_pages_resolves():
    """What the site build reads, checked in a second: a role that names a missing row fails here first."""
    bad = []
    for page in pages():
        for spec in ROLE.findall(page.read_text()):
            try:
                resolve(spec)
            except ResultError as e:
                bad.append(f"{page.relative_to(ROOT)}: {e}")
    assert not bad, bad


# -- no typed copies ----------------------------------------------------------------------------------------
#: numbers with a decimal point and at least 3 significant digits, as a page would print them
_NUM = re.compile(r"(?<![\w.^/-])(\d+\.\d+(?:e-?\d+)?|\d\.?\d*e-?\d+)(?![\w.]|\d)")
#: numbers a page states that a run's files also print as another quantity (each needed: a page types it and a
#: committed report prints it): the paper's 1.15 and 1.18, and its MLE over its HCR-hat, 1.21 (its table); 11.64 and
#: 11.4, numbers of the paper's table (paper-details.md); test_predicted's 1.14, and 1.22 and 1.15, benchmark rows of
#: performance.md; the transient guide's F_ξ/F = 1.09 (a test's toy); 1.85 and 10.8, the trials guide's one-off
#: 64-trial ratio and the calibration script's 40 × 30 limits (paper-details.md); 2.54, the paper's viewpoint grid
#: spacing in cm (the map config's 0.0254 m); 1.12, a θ of the demo's grid (its config's range), where the planning
#: model's heavy tails were measured (choosing-budgets.md); 14.4, a number of the paper's table, and 1.53, the
#: calibration script's µs per pixel-sample (performance.md), 2.17, a calibration limit (paper-details.md), 27.8, a
#: number of the paper's table, and 23.5, the measuring machines' GiB (performance.md, reproducibility.md), which
#: decisive_curve's report prints as other quantities (precisions reached, in %)
ALLOWED = {"1.09", "1.12", "1.14", "1.15", "1.18", "1.21", "1.22", "1.85", "10.8", "11.4", "11.64", "14.4", "1.53",
           "2.17", "2.54", "23.5", "27.8", "10.1"}


def _significant(text: str) -> int:
    mantissa = text.split("e")[0].replace(".", "").lstrip("0")
    return len(mantissa)


def printed_by_runs() -> set[str]:
    """The numbers the committed runs print for people: every report.md, as written."""
    out = set()
    for report in (ROOT / "results").glob("*/report.md"):
        out |= {n for n in _NUM.findall(report.read_text()) if _significant(n) >= 3}
    stated = set()  # a config's settings (Θ, grids, σ) are inputs a page may state, not results
    for config in (ROOT / "configs").glob("*.yaml"):
        stated |= {n for line in config.read_text().splitlines() for n in _NUM.findall(line.split("#")[0])}
    return out - ALLOWED - stated


def typed_numbers(text: str) -> list[str]:
    text = ROLE.sub("", text)
    text = re.sub(r"```.*?```", "", text, flags=re.S)  # code: commands and their arguments
    text = re.sub(r"`[^`]*`", "", text)
    return [n for n in _NUM.findall(text) if _significant(n) >= 3]


def test_no_number_a_run_printed_is_typed_into_the_docs_or_readme():
    printed = printed_by_runs()
    assert len(printed) > 100
    hits = [f"{p.relative_to(ROOT)}: {n}" for p in [ROOT / "README.md", *pages()]
            for n in typed_numbers(p.read_text()) if n in printed]
    assert not hits, hits


def test_the_readmes_numbers_are_the_committed_runs():
    """GitHub shows the README as written, so its few numbers are checked here against the files they come
    from: the rise of the decisive curve's quoted HCR lower end (AWGN) from 0.85 m (line of sight) to 1.3 m (beyond
    the corner), that run's minutes and pixel-samples, and the demo's time. The site's front page shows the same
    figure with the rise in its alt text, where no role can go."""
    readme = (ROOT / "README.md").read_text()
    quoted = "decisive_curve/00-bounds/precise.csv[noise_index=0, theta_object_position={}] hcr_lower :.3f"
    rise = float(resolve(quoted.format(1.3)).replace("−", "-")) - float(resolve(quoted.format(0.85)).replace("−", "-"))
    assert readme.count(f"{rise:.1f} decades") == 2, rise  # the figure's alt text and its caption
    index = (ROOT / "docs" / "index.md").read_text()  # the same figure on the site's front page
    assert index.count(f"{rise:.1f} decades") == 2, rise
    minutes = float(resolve("decisive_curve/machine.json seconds_total :.1f")) / 60
    samples = float(resolve("decisive_curve/00-bounds/precise.csv max(precision_pixel_samples) :.3g"))
    assert f"{minutes:.0f} min, {samples:.2g} pixel-samples".replace("e+0", "e") in readme, (minutes, samples)
    seconds = float(resolve("quick/machine.json seconds_total :.1f"))
    assert f"its studies in {seconds:.0f} s" in readme, seconds
