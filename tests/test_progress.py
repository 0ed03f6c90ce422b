"""Console output of a run: one progress bar per stage (replicate sets of a stage extend one bar), no bar
for work the render bank already has, and a warning shown once per run by the run's process, not once per
worker (a scene's load warning, a warning raised in every task)."""
import io
import os
import warnings

import pytest

import nlosbench as nb
from nlosbench import scenes
from nlosbench.bank import RenderBank
from nlosbench.executors import LocalPoolExecutor
from nlosbench.studies.progress import Progress, stage


def bars(text: str) -> list[str]:
    """The final state of every bar drawn to `text` (tqdm redraws a bar with '\\r'; a closed bar ends its line)."""
    return [line.rsplit("\r", 1)[-1] for line in text.split("\n") if line.strip()]


def test_replicates_of_a_stage_extend_one_bar_and_empty_stages_draw_none():
    out = io.StringIO()
    progress = Progress(file=out)
    for r in range(3):
        assert list(progress(range(4), desc=f"grid renders (replicate {r})")) == [0, 1, 2, 3]
    assert list(progress([], total=0, desc="cached renders (replicate 0)")) == []
    assert list(progress(range(2), desc="trials")) == [0, 1]
    progress.close()
    drawn = bars(out.getvalue())
    assert len(drawn) == 2, drawn
    assert drawn[0].startswith("grid renders:") and "12/12" in drawn[0]
    assert drawn[1].startswith("trials:") and "2/2" in drawn[1]
    assert "cached" not in out.getvalue()
    assert stage("FD Jacobians (round 2)") == "FD Jacobians" and stage("clean images (one per trial)") == \
        "clean images (one per trial)"


def test_a_nested_stage_does_not_close_the_bar_it_runs_in():
    out = io.StringIO()
    progress = Progress(file=out)
    for _ in progress(range(2), desc="gradients"):
        for r in range(2):
            list(progress(range(3), desc=f"renders (replicate {r})"))
    progress.close()
    drawn = out.getvalue()
    assert "gradients: 100%" in drawn and "2/2" in drawn  # the outer bar counted to its end
    assert drawn.count("0/3 ") == 1 and "12/12" in drawn  # the inner stage: one bar, over both passes
    assert Progress(quiet=True)(range(3), desc="x") == range(3)


def test_no_bar_for_renders_the_bank_already_has():
    out = io.StringIO()
    progress = Progress(file=out)
    bank = RenderBank(nb.scenes.get("blob2d"), progress=progress)
    thetas = [[0.4, 0.5], [0.5, 0.5], [0.6, 0.4]]
    first = [bank.at(thetas, 16, "grid", common=True, replicate=r, desc=f"grid renders (replicate {r})")
             for r in range(2)]
    progress.close()
    drawn = out.getvalue()
    assert len(bars(drawn)) == 1 and "6/6" in drawn
    again = [bank.at(thetas, 16, "grid", common=True, replicate=r, desc=f"grid renders (replicate {r})")
             for r in range(2)]
    progress.close()
    assert out.getvalue() == drawn  # everything cached: nothing drawn
    assert all((a == b).all() for a, b in zip(first, again, strict=True)) and bank.renders == 6


def probe(model, x):
    warnings.warn("probe: raised by every task in every worker", UserWarning, stacklevel=1)
    return x, os.getpid()


def test_a_scene_warning_is_shown_once_per_run_not_once_per_worker(tmp_path, capfd):
    src = (nb.scenes.SCENE_DIR / "cornell_ball.xml").read_text()
    (tmp_path / "g.xml").write_text(src.replace('<rfilter type="box"/>', '<rfilter type="gaussian"/>'))
    (tmp_path / "g.yaml").write_text("file: g.xml\nparams:\n  - {name: x, kind: translate, object: ball, "
                                     "axis: [1, 0, 0], lower: -0.3, upper: 0.3, default: 0}\n")
    spec = {"name": str(tmp_path / "g.yaml"), "options": {"defines": {"res": 8}}}
    with pytest.warns(UserWarning, match="GaussianFilter is not a box filter"):
        scenes.build(spec)  # the run's own process loads the scene and warns
    with warnings.catch_warnings(record=True) as seen, LocalPoolExecutor(spec, workers=2) as pool:
        warnings.simplefilter("always")
        pids = {pid for _, pid in pool.imap_unordered(probe, range(6))}
    assert pids and os.getpid() not in pids
    err = capfd.readouterr().err
    assert "box filter" not in err and "probe" not in err, err  # workers print nothing themselves
    assert [str(w.message) for w in seen] == ["probe: raised by every task in every worker"]  # shown here, once
