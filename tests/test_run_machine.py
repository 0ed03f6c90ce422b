"""A run writes machine.json when it finishes (the machine, its load, the versions, the wall time, the command as
called), and scripts/publish_result.py copies it rather than describing the machine that publishes."""
import importlib.util
import json
import sys
from pathlib import Path

import pytest
import yaml

from nlosbench.cli import main

ROOT = Path(__file__).resolve().parents[1]
STUDY = {"type": "bounds", "id": "b", "grid": {"start": 0.2, "stop": 0.8, "num": 3}, "spp": 4, "replicates": 3,
         "zzb": False, "save_images": False}


def _publisher():
    spec = importlib.util.spec_from_file_location("publish_result", ROOT / "scripts" / "publish_result.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_a_run_writes_its_machine_its_load_and_the_command_it_was_called_with(tmp_path):
    cfg = tmp_path / "tiny.yaml"
    cfg.write_text(yaml.safe_dump({"name": "tiny", "seed": 5, "scene": {"name": "blob2d", "params": ["x"]},
                                   "noise": [{"model": "awgn", "sigma": 0.3}], "executor": {"type": "serial"},
                                   "cache": None, "studies": [STUDY]}))
    out = tmp_path / "run"
    assert main(["run", str(cfg), "--set", "seed=3", "--out", str(out), "--quiet"]) == 0
    m = json.loads((out / "machine.json").read_text())
    results = json.loads((out / "results.json").read_text())
    assert m["command"] == f"nlosbench run {cfg} --set seed=3 --out {out}"
    assert m["seconds_total"] == results["seconds_total"] and list(m["studies"]) == ["b"]
    assert m["studies"]["b"]["renders"] == results["studies"]["b"]["results"]["renders"] > 0
    if sys.platform.startswith("linux"):
        loads = m["load"]["averages"]
        assert set(loads) == {"start", "b"} and all(len(v) == 3 and min(v) >= 0 for v in loads.values())
        assert m["load"]["max_1min"] == max(v[0] for v in loads.values())
    assert m["cores"] >= 1 and m["versions"]["mitsuba"] and m["variant"]
    dest = _publisher().publish(out, "tiny", tmp_path / "results")
    assert json.loads((dest / "machine.json").read_text()) == m and (dest / "report.md").is_file()


def test_publishing_a_run_without_machine_json_is_refused(tmp_path):
    run = tmp_path / "old"
    run.mkdir()
    (run / "results.json").write_text(json.dumps({"studies": {"b": {"status": "done"}}}))
    with pytest.raises(SystemExit, match="no machine.json"):
        _publisher().publish(run, "old", tmp_path / "results")
    assert not (tmp_path / "results" / "old").exists()


def test_a_config_inside_the_repository_is_named_relative_to_it(monkeypatch):
    from nlosbench.experiment.machine import command

    monkeypatch.delenv("NLOSBENCH_VARIANT", raising=False)
    assert command(ROOT / "configs" / "quick.yaml", ["seed=1"], "runs/quick") == (
        "nlosbench run configs/quick.yaml --set seed=1 --out runs/quick")
    monkeypatch.setenv("NLOSBENCH_VARIANT", "cuda_ad_rgb")
    assert command(ROOT / "configs" / "quick.yaml", (), "runs/q", smoke=True) == (
        "NLOSBENCH_VARIANT=cuda_ad_rgb nlosbench run configs/quick.yaml --smoke --out runs/q")
