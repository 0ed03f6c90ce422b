"""Config validation, the CLI and the runner end to end (real renders on cornell_ball, tiny sizes)."""
import json
from pathlib import Path

import pytest
import yaml

from nlosbench.cli import main
from nlosbench.experiment import config
from nlosbench.schema import ConfigError, Field, validate_block

CFG = Path(__file__).parent / "configs" / "cornell_bounds.yaml"
ROOT = Path(__file__).resolve().parents[1]


def _write(tmp_path, mutate) -> Path:
    raw = yaml.safe_load(CFG.read_text())
    mutate(raw)
    p = tmp_path / "c.yaml"
    p.write_text(yaml.safe_dump(raw))
    return p


@pytest.mark.parametrize("mutate, message", [
    (lambda c: c.update(sede=3), "sede: unknown key; did you mean 'seed'?"),
    (lambda c: c.update(seed="three"), "seed: expected an integer, got str 'three'"),
    (lambda c: c["studies"][0].update(spp="many"), "studies[0].spp: expected an integer"),
    (lambda c: c["studies"][0].update(gird=[0.1]), "did you mean 'grid'?"),
    (lambda c: c["studies"][0].update(type="bound"), "did you mean 'bounds'?"),
    (lambda c: c["noise"][0].update(model="gauss"), "noise[0].model: expected one of"),
    (lambda c: c["noise"][0].update(sigma=-1.0), "noise[0].sigma: awgn needs sigma > 0"),
    (lambda c: c["scene"].update(name="scenes/nosuch.yaml"), "nosuch.yaml does not exist"),
    (lambda c: c["studies"].append({"type": "trials", "theta": [0.0], "estimators": [{"name": "mle-adamm"}]}),
     "studies[2].estimators[0].name: unknown estimator 'mle-adamm'; did you mean 'mle-adam'?"),
])
def test_config_errors_are_one_clear_line_and_write_nothing(tmp_path, capsys, mutate, message):
    out = tmp_path / "run"
    rc = main(["run", str(_write(tmp_path, mutate)), "--out", str(out), "--quiet"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and message in err and len(err.splitlines()) == 1, err
    assert not out.exists()


def test_overrides_and_defaults():
    cfg = config.load(CFG, ["seed=7", "studies.0.spp=8", "noise.0.sigma=0.5"])
    assert cfg["seed"] == 7 and cfg["studies"][0]["spp"] == 8 and cfg["noise"][0]["sigma"] == 0.5
    assert cfg["studies"][0]["crlb"] is True  # default filled in
    with pytest.raises(ConfigError, match="key.path=value"):
        config.load(CFG, ["seed"])


def test_a_relative_scene_spec_is_read_from_the_configs_folder(tmp_path, monkeypatch):
    """`scene.name: scenes/x.yaml` beside the config is found from any working folder; a path that is not
    beside the config is left to the working folder (as before)."""
    import shutil

    (tmp_path / "exp" / "scenes").mkdir(parents=True)
    for f in ("cornell_ball.yaml", "cornell_ball.xml"):
        shutil.copy(ROOT / "scenes" / f, tmp_path / "exp" / "scenes" / f)
    cfg_path = tmp_path / "exp" / "c.yaml"
    cfg_path.write_text(yaml.safe_dump({"name": "rel", "scene": {"name": "scenes/cornell_ball.yaml"},
                                        "noise": [{"model": "awgn", "sigma": 1.0}],
                                        "studies": [{"type": "bounds", "grid": [0.1, 0.2]}]}))
    monkeypatch.chdir(tmp_path)
    assert config.load(cfg_path)["scene"]["name"] == str(tmp_path / "exp" / "scenes" / "cornell_ball.yaml")
    monkeypatch.chdir(ROOT)  # not beside the config: left as written, read from the working folder
    cfg_path.write_text(cfg_path.read_text().replace("scenes/cornell_ball.yaml", "scenes/pi_hallway.yaml"))
    assert config.load(cfg_path)["scene"]["name"] == "scenes/pi_hallway.yaml"


def test_defaults_are_copies():
    """A study that edits its validated block (a default list or mapping) leaves the schema's default alone."""
    schema = {"spp": Field(list, [64, 256]), "at": Field(dict, {})}
    a = validate_block({}, schema)
    a["spp"].append(1024)
    a["at"]["x"] = 0.1
    assert validate_block({}, schema) == {"spp": [64, 256], "at": {}}


def test_every_shipped_config_validates():
    root = Path(__file__).parents[1] / "configs"
    paths = sorted(root.glob("*.yaml")) + [CFG]
    assert paths
    for p in paths:
        config.load(p)


@pytest.fixture(scope="module")
def first_run(tmp_path_factory) -> Path:
    """CFG run once into a folder of its own: the report test re-reports and resumes it, the executor test compares
    its bounds.csv with a rerun's and a pool's."""
    out = tmp_path_factory.mktemp("first") / "run"
    assert main(["run", str(CFG), "--out", str(out), "--quiet"]) == 0
    return out


def test_run_then_report_reproduces_tables(first_run):
    out = first_run
    report = (out / "report.md").read_text()
    assert "## 00-bounds" in report and "## 01-fisher-maps" in report and "| AWGN(sigma=0.1) |" in report
    results = json.loads((out / "results.json").read_text())
    assert results["studies"]["00-bounds"]["results"]["grid_points"] == 7
    assert (out / "00-bounds" / "bounds.png").stat().st_size > 0
    assert len(list((out / "00-bounds" / "images").glob("*.exr"))) == 7
    assert yaml.safe_load((out / "config.yaml").read_text())["seed"] == 1  # resolved config kept
    (out / "report.md").unlink()
    (out / "00-bounds" / "bounds.png").unlink()
    assert main(["report", str(out)]) == 0
    assert (out / "report.md").read_text() == report and (out / "00-bounds" / "bounds.png").exists()
    # a second run into the same folder is refused; --resume skips finished studies (their records stay as they were)
    assert main(["run", str(CFG), "--out", str(out), "--quiet"]) == 2
    assert main(["run", str(CFG), "--out", str(out), "--quiet", "--resume"]) == 0
    assert json.loads((out / "results.json").read_text())["studies"] == results["studies"]


def test_same_config_same_numbers_on_any_executor(tmp_path, first_run):
    """Seeds are derived per grid point, so a second run, on a 2-process pool, gives the first (in-process) run's
    bounds byte for byte: a rerun and another executor at once."""
    extra = ["--set", "executor.type=local", "--set", "executor.workers=2"]
    assert main(["run", str(CFG), "--out", str(tmp_path / "pool"), "--quiet", *extra]) == 0
    first = (first_run / "00-bounds" / "bounds.csv").read_text()
    assert (tmp_path / "pool" / "00-bounds" / "bounds.csv").read_text() == first


SHIPPED = sorted((Path(__file__).parents[1] / "configs").glob("*.yaml"))


@pytest.mark.parametrize("path", [p if p.stem == "quick" else pytest.param(p, marks=pytest.mark.slow) for p in SHIPPED],
                         ids=[p.stem for p in SHIPPED])  # the demo's config in `make test`, the others `make test-slow`
def test_every_shipped_config_runs_in_smoke_mode(tmp_path, path):
    """`--smoke` shrinks image, grids, spp and trials but runs every study through the same code path."""
    cfg = config.load(path, smoke=True)
    full = config.load(path)
    assert [s["type"] for s in cfg["studies"]] == [s["type"] for s in full["studies"]]
    out = tmp_path / "run"
    cache = ["--set", f"cache={tmp_path / 'cache'}"] if full["cache"] else []  # not the repository's runs/
    # the demo's in this process (16 s against 25 s wall on 2 cores: two workers cost more to start than its 8-spp
    # renders); a pool runs the same tasks in test_executors and test_same_config_same_numbers_on_any_executor
    serial = ["--set", "executor.type=serial"] if path.stem == "quick" else []
    assert main(["run", str(path), "--smoke", "--out", str(out), "--quiet", *cache, *serial]) == 0
    results = json.loads((out / "results.json").read_text())
    assert [s["status"] for s in results["studies"].values()] == ["done"] * len(cfg["studies"])
    report = (out / "report.md").read_text()
    for i, s in enumerate(cfg["studies"]):
        assert f"## {i:02d}-{s['type']}" in report or f"## {s['id']}" in report
    if path.stem == "quick":  # what `make demo` promises: the HCR curve, the Fisher maps, the trial table
        assert "bounds.png)" in report and "fisher_maps.png)" in report
        # its maps are at one FD step: their CRLBs' lower ends say the step was not checked, not that it diverged
        assert "† not a confidence limit: the FD step was not checked (one step" in report
        assert "| θ* |" in report and (out / "00-bounds" / "bounds.png").stat().st_size > 0


def test_render_and_list_commands(tmp_path, capsys):
    assert main(["render", "cornell_ball", "--theta", "0.1", "0.3", "0.8", "--spp", "8", "--out", str(tmp_path)]) == 0
    assert list(tmp_path.glob("*.exr")) and list(tmp_path.glob("*.png"))
    assert main(["list", "scenes"]) == 0
    listed = [line.split(": ", 1)[0] for line in capsys.readouterr().out.splitlines()]  # "name: description"
    assert {"blob2d", "edge1d", "cornell_ball"} <= set(listed)
    assert main(["render", "cornell_ball", "--theta", "9", "0.3", "0.8", "--out", str(tmp_path)]) == 2


SCENES = {"edge": ({"name": "edge1d"}, [0.5]), "blob": ({"name": "blob2d"}, [[0.5, 0.5]]),
          "pi": ({"name": "pi_hallway", "options": {"defines": {"width": 16, "height": 12, "max_depth": 3}}}, [0.9])}


@pytest.mark.parametrize("scene, study, message", [
    ("edge", {"type": "bounds", "grid": {"start": 0.5, "stop": 0.95, "num": 5}},
     "01-bounds.grid: θ out of range: edge=0.95 outside [0.1, 0.9]"),
    ("edge", {"type": "fisher-maps", "at": [0.5], "fd_rounds": 1},
     "01-fisher-maps.fd_rounds: the unbiased Fisher information needs >= 2 rounds, got 1"),
    ("edge", {"type": "fisher-maps", "at": [0.5], "gradient": {"method": "ad", "integrator": "path"}},
     "01-fisher-maps.gradient: AD backend: integrator must be one of"),
    ("edge", {"type": "fisher-maps", "at": [0.5], "gradient": {"method": "fd", "step": 0.01}},
     "01-fisher-maps.gradient: FD Jacobians take `fd_step`"),
    ("edge", {"type": "fisher-maps", "at": [0.5], "gradient": {"method": "ad"}, "precision": 0.2},
     "01-fisher-maps.precision: a precision target plans fresh FD rounds"),
    ("edge", {"type": "trials", "theta": [0.5], "n": 0, "estimators": [{"name": "grid-search"}]},
     "01-trials.n: expected a positive integer, got 0"),
    ("edge", {"type": "inexact", "theta": [0.95], "deltas": [0.1]}, "01-inexact.theta: θ out of range"),
    ("blob", {"type": "gradients", "seeds": 1}, "01-gradients.seeds: expected an integer >= 2"),
    ("blob", {"type": "gradients", "at": {"z": 0.5}}, "01-gradients.at.z: unknown parameter"),
    ("pi", {"type": "viewpoints", "num": 4}, "01-viewpoints.num: num must be a positive odd number"),
    ("pi", {"type": "viewpoints", "at": [2.5]}, "01-viewpoints.at: θ out of range"),
    ("pi", {"type": "viewpoint-search", "fd_rounds": 2}, "01-viewpoint-search.fd_rounds: expected an integer >= 3"),
    ("pi", {"type": "viewpoint-search", "box": [[0.1, 0.3], [-0.3, 0.3]]},
     "01-viewpoint-search.box: expected two [low, high] pairs around the standard view"),
    ("pi", {"type": "viewpoint-search", "grid": "nowhere"},
     "01-viewpoint-search.grid: no `viewpoints` study with id 'nowhere' before this one"),
    ("edge", {"type": "fidelity", "grid": [0.3, 0.5, 0.7], "spp": [9], "bins": [1, 3]},
     "01-fidelity.bins: b = 3 does not divide the 1×64 image"),
])
def test_every_study_checks_its_block_before_anything_is_written(tmp_path, capsys, scene, study, message):
    """Each study's plan() runs on the resolved config, with the scene loaded, for every study of the file
    before the run folder is made: a bad value in the second study is one line (exit 2) and nothing of the
    first study ran or was written."""
    spec, at = SCENES[scene]
    raw = {"name": "b", "scene": spec, "noise": [{"model": "awgn", "sigma": 0.1}], "executor": {"type": "serial"},
           "studies": [{"type": "fisher-maps", "at": at, "spp": 4}, study]}
    cfg = tmp_path / "c.yaml"
    cfg.write_text(yaml.safe_dump(raw))
    out = tmp_path / "run"
    rc = main(["run", str(cfg), "--out", str(out), "--quiet"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and err.startswith(f"nlosbench: error: {message}") and len(err.splitlines()) == 1, err
    assert not out.exists()
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    assert main(["run", str(cfg), "--out", str(out), "--quiet"]) == 2
    assert [p.name for p in out.iterdir()] == ["notes.txt"] and (out / "notes.txt").read_text() == "mine"
