"""`nlosbench check-scene`: each binding's image change at Θ's ends, and the warnings of its heuristics."""
import importlib.util
import json
import shutil
from pathlib import Path

from nlosbench.cli import BAD_INPUT, main
from nlosbench.scenes.check import check_scene, format_report

ROOT = Path(__file__).resolve().parents[1]
XML = ROOT / "examples" / "own_scene" / "room.xml"

# a sphere behind the room's back wall: no camera ray and no light path of depth ≤ 3 reaches it
GHOST = """    <shape type="sphere" id="ghost">
        <point name="center" x="0" y="-0.3" z="-2"/>
        <float name="radius" value="0.3"/>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.5, 0.5, 0.5"/></bsdf>
    </shape>
</scene>"""

BAD_SPEC = """file: room.xml
params:
  - {name: ghost_paint, kind: reflectance, key: ghost.bsdf.reflectance.value, channel: 0, lower: 0.2, upper: 0.9,
     default: 0.5, units: "1"}
  # offsets -1 → 0 keep the ghost behind the wall (z = -3 → -2); +1 brings it half into the room (z = -1)
  - {name: ghost_z, kind: translate, object: ghost, axis: [0, 0, 1], lower: -1.0, upper: 1.0, default: 0.0}
  # 3 m to the right takes the crate through the right wall and out of the camera's view
  - {name: crate_far, kind: translate, object: crate, axis: [1, 0, 0], lower: 0.0, upper: 3.0, default: 0.0}
"""


def example_spec() -> str:
    """The scene spec the worked example writes (examples/own_scene.py: SPEC)."""
    spec = importlib.util.spec_from_file_location("own_scene", ROOT / "examples" / "own_scene.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.SPEC


def scene(tmp_path: Path, spec: str, xml: str | None = None) -> Path:
    """A scene folder with room.xml (or `xml`) and the spec room.yaml; returns the spec's path."""
    d = tmp_path / "scene"
    d.mkdir()
    if xml is None:
        shutil.copy(XML, d / "room.xml")
    else:
        (d / "room.xml").write_text(xml)
    (d / "room.yaml").write_text(spec)
    return d / "room.yaml"


def test_the_examples_spec_passes_with_every_binding_moving_its_object(tmp_path, capsys):
    spec = scene(tmp_path, example_spec())
    assert main(["check-scene", str(spec), "--spp", "32", "--out", str(tmp_path / "out")]) == 0
    text = capsys.readouterr().out
    assert "no warnings" in text and "warning:" not in text
    result = json.loads((tmp_path / "out" / "check.json").read_text())
    assert (tmp_path / "out" / "check.png").stat().st_size > 10_000
    assert [p["name"] for p in result["params"]] == ["crate_x", "crate_size", "crate_paint"]
    assert result["repeat_diff"] == 0.0  # box filter on the CPU: identical calls, identical images
    for p in result["params"]:
        assert p["thetas"][0] < p["thetas"][1] < p["thetas"][2]
        for s in p["steps"]:
            assert s["total"] > 0 and 0 < s["changed"] <= 1 and 0 < s["visible"] <= s["changed"]
            assert s["border"] < 0.2  # the crate sits in the middle of the image: little change at the border
        assert p["frame"] == (["inside"] * 3 if p["kind"] in ("translate", "radius") else [])
    # moving the crate changes more of the image than repainting it
    by = {p["name"]: p for p in result["params"]}
    assert by["crate_x"]["steps"][0]["visible"] > by["crate_paint"]["steps"][0]["visible"]


def test_a_binding_that_moves_nothing_a_flat_half_and_an_object_leaving_the_frame_are_warned(tmp_path, capsys):
    spec = scene(tmp_path, BAD_SPEC, XML.read_text().replace("</scene>", GHOST))
    assert main(["check-scene", str(spec), "--spp", "32", "--out", str(tmp_path / "out")]) == 0
    text = capsys.readouterr().out
    warnings = [line for line in text.splitlines() if line.startswith("warning: ")]
    assert len(warnings) == 3, text
    assert "ghost_paint: no pixel changes between θ = 0.2 and 0.9" in warnings[0]
    assert "moves nothing" in warnings[0]
    assert "ghost_z: no pixel changes between lower and mid" in warnings[1]
    assert "crate_far" in warnings[2] and "outside at upper (3 m)" in warnings[2]
    result = json.loads((tmp_path / "out" / "check.json").read_text())
    ghost, ghost_z, far = result["params"]
    assert all(s["total"] == 0 and s["changed"] == 0 for s in ghost["steps"])
    assert ghost_z["steps"][0]["changed"] == 0 < ghost_z["steps"][1]["changed"]
    assert ghost_z["frame"] == ["inside"] * 3  # hidden by the wall, yet inside the frame: occlusion is not seen
    assert far["frame"][0] == "inside" and far["frame"][2] == "outside"


def test_a_non_box_pixel_filter_is_warned(tmp_path, capsys):
    xml = XML.read_text().replace('<rfilter type="box"/>', '<rfilter type="gaussian"/>')
    assert xml != XML.read_text()
    spec = scene(tmp_path, "file: room.xml\nparams:\n  - {name: paint, kind: reflectance, key: "
                           "crate.bsdf.reflectance.value, lower: 0.5, upper: 1.5, default: 1.0}\n", xml)
    result = check_scene(str(spec), spp=16)  # the model's own load warning is restated once, not twice
    assert sum("not a box filter" in w for w in result.warnings) == 1
    assert result.params[0].steps[0].changed > 0
    assert "warning: pixel filter GaussianFilter is not a box filter" in format_report(result)


def test_a_bad_spec_path_is_one_line_and_exit_2(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["check-scene", "missing/room.yaml"]) == BAD_INPUT
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "missing/room.yaml" in err[0] and "does not exist" in err[0]
    assert list(tmp_path.iterdir()) == []  # nothing written


def test_a_default_that_is_not_the_xmls_value_is_warned_without_a_render(tmp_path, capsys):
    """θ = the spec's default must leave the scene as the XML has it: a translate default of 0.2 m moves the crate
    (warned, in the text and check.json; the example's spec, whose defaults agree, has no warning: above). The
    comparison of the mi.traverse values renders nothing."""
    from nlosbench.scenes import get
    from nlosbench.scenes.check import default_agreement

    spec = scene(tmp_path, "file: room.xml\ndefines: {resx: 8, resy: 6, max_depth: 2}\nparams:\n"
                           "  - {name: crate_x, kind: translate, object: crate, axis: [1, 0, 0], lower: -0.5, "
                           "upper: 0.5, default: 0.2}\n")
    model = get(str(spec))
    agree = default_agreement(model)
    assert model.stats.renders == 0
    assert agree["crate_x"][0] == "crate.vertex_positions" and agree["crate_x"][1] > 0.19 and not agree["crate_x"][2]
    assert main(["check-scene", str(spec), "--spp", "2", "--out", str(tmp_path / "out")]) == 0
    text = capsys.readouterr().out
    assert "crate_x: θ = its default 0.2 m does not leave the scene as the XML has it" in text, text
    result = json.loads((tmp_path / "out" / "check.json").read_text())
    assert result["params"][0]["default_ok"] is False and result["params"][0]["default_diff"] > 0.19
    assert any("crate_x: θ = its default" in w for w in result["warnings_all"])
