"""`nlosbench init-scene`: a plain Mitsuba XML file → its mi.traverse keys and a scene spec that `check-scene`
accepts, on the Cornell box (cornell_ball.xml) and on the tutorials' room (examples/own_scene/room.xml)."""
import math
import shutil
from pathlib import Path

import pytest

import nlosbench as nb
from nlosbench.cli import BAD_INPUT, main
from nlosbench.scenes import read_spec
from nlosbench.scenes.check import check_scene

ROOT = Path(__file__).resolve().parents[1]
TINY = {"res": "12", "max_depth": "2"}


def test_the_cornell_box_becomes_a_checked_spec_and_a_crlb(tmp_path, capsys):
    xml = Path(shutil.copy(ROOT / "scenes" / "cornell_ball.xml", tmp_path))
    assert main(["init-scene", str(xml)]) == 0
    out = capsys.readouterr().out
    assert "ball             centre (0, -0.6, 0.1) m, size 0.3 m" in out  # the sphere's centre and radius
    assert "light.emitter.radiance.value" in out and "res = 32, max_depth = 4" in out
    spec = read_spec(tmp_path / "cornell_ball.yaml")
    assert spec["file"] == "cornell_ball.xml"
    assert [q["name"] for q in spec["params"]] == ["ball_x", "ball_y", "ball_z", "ball_radius", "ball_paint"]
    report = check_scene(str(tmp_path / "cornell_ball.yaml"), spp=4, defines=TINY)
    assert report.all_warnings == []  # every binding moves what it claims, the ball stays in view
    b = nb.bound(str(tmp_path / "cornell_ball.yaml"), "ball_x", 0.0, nb.noise.AWGN(sigma=0.01), spp=64, fd_step=0.08,
                 max_halvings=1, test_grid=5, options={"defines": TINY})
    crlb = b.point.bounds["crlb"]
    assert math.isfinite(crlb.log10) and crlb.lower <= crlb.log10 <= crlb.upper
    assert f"CRLB {10**crlb.log10:.3g} m²" in b.line()


def test_the_tutorial_room_binds_its_crate_not_its_camera_or_lamp(tmp_path, capsys):
    spec = tmp_path / "specs" / "room.yaml"
    assert main(["init-scene", str(ROOT / "examples" / "own_scene" / "room.xml"), "--out", str(spec)]) == 0
    out = capsys.readouterr().out
    assert "a camera (translate only)" in out and "emits light" in out and "[crate.vertex_positions]" in out
    s = read_spec(spec)
    assert (spec.parent / s["file"]).resolve() == (ROOT / "examples" / "own_scene" / "room.xml").resolve()
    assert {q["object"] for q in s["params"] if "object" in q} == {"crate"}
    assert "#  - {name: camera_x, kind: translate" in spec.read_text()  # the others: commented, no radius for it
    assert "camera_radius" not in spec.read_text()


@pytest.mark.parametrize("make, argv, message", [
    (None, ["missing.xml"], "missing.xml: does not exist"),
    ("not xml", ["bad.xml"], "bad.xml: is not an XML file"),
    ("<scene version='3.0.0'><shape type='nope'/></scene>", ["bad.xml"], "bad.xml: does not load"),
    ("<scene version='3.0.0'/>", ["bad.xml", "--out", "bad.txt"], "--out: expected a .yaml path"),
    ("<scene version='3.0.0'/>", ["bad.xml"], "has no shape with an id to bind"),
])
def test_bad_input_is_one_line_and_writes_nothing(tmp_path, monkeypatch, capsys, make, argv, message):
    monkeypatch.chdir(tmp_path)
    if make is not None:
        Path("bad.xml").write_text(make)
    assert main(["init-scene", *argv]) == BAD_INPUT
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err
    assert sorted(p.name for p in tmp_path.iterdir()) == (["bad.xml"] if make else [])


def test_an_existing_spec_is_kept_without_force_and_an_unknown_object_named(tmp_path, capsys):
    xml = Path(shutil.copy(ROOT / "scenes" / "cornell_ball.xml", tmp_path))
    (tmp_path / "cornell_ball.yaml").write_text("mine")
    assert main(["init-scene", str(xml)]) == BAD_INPUT
    assert "exists; pass --force" in capsys.readouterr().err and (tmp_path / "cornell_ball.yaml").read_text() == "mine"
    assert main(["init-scene", str(xml), "--force", "--object", "teapot"]) == BAD_INPUT
    assert "'teapot' is not a shape with an id" in capsys.readouterr().err
    assert main(["init-scene", str(xml), "--force", "--object", "floor", "--object", "ball"]) == 0
    names = [q["name"] for q in read_spec(tmp_path / "cornell_ball.yaml")["params"]]
    assert names[:4] == ["floor_x", "floor_y", "floor_z", "floor_radius"] and "ball_paint" in names
