"""README.md is a landing page whose Python example runs and says what it computes."""
import contextlib
import io
import math
import re
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()


def python_block(heading: str) -> str:
    """The first ```python block under the `## heading` section."""
    section = README.split(f"## {heading}\n", 1)[1].split("\n## ", 1)[0]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


def test_the_first_bound_example_runs_and_matches_the_closed_form():
    out = io.StringIO()
    scope: dict = {}
    with contextlib.redirect_stdout(out):
        exec(compile(python_block("First bound in Python"), "README.md", "exec"), scope)
    assert "HCR ≥ 10^" in out.getvalue() and "renders" in out.getvalue()
    curve, noise, model = scope["curve"], scope["noise"], scope["model"]
    assert abs(float(curve.points[10].theta[0]) - 0.5) < 1e-12  # "θ* = 0.5 m", as the comment says
    # AWGN: F = ‖∂L/∂x‖² / σ², exact for the analytic toy; the example's CRLB is FD over 2 cm grid neighbours
    y = torch.tensor(0.5, dtype=torch.float64)
    full = scope["nb"].scenes.get("blob2d")
    J = torch.autograd.functional.jacobian(lambda v: full.clean(torch.stack([v, y])),
                                           torch.tensor(0.5, dtype=torch.float64))
    exact = math.log10(noise.sigma**2 / float((J**2).sum()))
    hcr, crlb_bound = scope["hcr"], scope["crlb"]
    crlb = crlb_bound.log10
    assert abs(crlb - exact) < 0.02, (crlb, exact)
    # the HCR's sup includes Δ → 0, whose limit is the CRLB: end for end, it is no lower
    assert hcr.log10 >= crlb_bound.lower - 1e-9 and hcr.point >= crlb_bound.point - 1e-9
    # the sentence after the example quotes the RMS error this bound allows
    mm = re.search(r"RMS error of about ([\d.]+) mm", README).group(1)
    assert f"{1e3 * 10 ** (crlb / 2):.1f}" == mm
    assert list(model.params.names) == ["x"]


def test_the_readme_is_a_short_landing_page_with_a_committed_figure():
    lines = README.splitlines()
    assert len(lines) <= 150, len(lines)
    figures = re.findall(r"!\[[^\]]*\]\(([^)]+)\)", README)
    assert figures and all((ROOT / f).is_file() for f in figures), figures
    assert "```bibtex" in README and "BSD-3-Clause" in README


def test_every_relative_link_of_the_readme_exists():
    links = [u.split("#")[0] for u in re.findall(r"\]\(([^)]+)\)", README) if not re.match(r"https?://", u)]
    assert len(links) > 5
    missing = [u for u in links if not (ROOT / u).exists()]
    assert not missing, missing


#: words about how the work was organised, not about the product: sessions, scratch runs, who had which machine,
#: issue numbers, a run's temporary output folder (the product's own /tmp/nlosbench-* files are named as such)
PROCESS_WORDS = re.compile(r"\bsession|\bscratch\b|earlier the same day|only one machine was available|no gpu was "
                           r"available|\bsaid here\b|\bissue \d|\bissue #|farm-bench|device tool|\blent\b|"
                           r"\.device/|\.\./shared/|/tmp/(?!nlosbench-)", re.I)


def test_no_words_about_how_the_work_was_organised():
    """User-facing text names machines and commands, not sessions, issue numbers or who had a GPU: the pages,
    configs, Makefile, and what a committed run's files say (report.md, and machine.json's command, which the run
    writes as it was called: a published run is made with `--out runs/NAME`)."""
    pages = [ROOT / "README.md", ROOT / "CHANGELOG.md", ROOT / "results" / "README.md", ROOT / "examples" / "README.md",
             ROOT / "Makefile", *sorted((ROOT / "docs").rglob("*.md")),
             *sorted((ROOT / "docs" / "tutorials").glob("*.py")), *sorted((ROOT / "configs").glob("*.yaml")),
             *sorted((ROOT / "results").glob("*/report.md")), *sorted((ROOT / "results").glob("*/machine.json"))]
    pages = [p for p in pages if "_build" not in p.parts and "generated" not in p.parts]
    pattern = PROCESS_WORDS
    hits = [f"{p.relative_to(ROOT)}: {m.group(0)}" for p in pages for m in pattern.finditer(p.read_text())]
    assert not hits, hits
