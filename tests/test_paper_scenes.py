"""The paper's scenes (real Mitsuba renders, tiny sizes): hallway + room with the ball's 860-point path,
and the Π-shaped hallway. Line of sight is checked exactly by casting rays from the camera."""
import numpy as np
import pytest

import nlosbench as nb

TINY = {"width": 32, "height": 64, "max_depth": 3}


@pytest.fixture(scope="module")
def hallway():
    return nb.scenes.get("hallway_room", defines=TINY)


@pytest.fixture(scope="module")
def pi():
    return nb.scenes.get("pi_hallway", defines={"width": 40, "height": 30, "max_depth": 3})


def point(k: int) -> float:
    """θ (arc length, m) of the paper's path point k = 1..860."""
    return (k - 1) * 0.01


def _shape(model, ident):
    return next(s for s in model.scene.shapes() if s.id() == ident)


def _camera(model) -> np.ndarray:
    import mitsuba as mi

    return np.array(mi.traverse(model.scene.sensors()[0])["to_world"].matrix).reshape(4, 4)[:3, 3]


def _cast(model, origins: np.ndarray, dirs: np.ndarray):
    import mitsuba as mi

    o = mi.Point3f(*(mi.Float(np.ascontiguousarray(np.broadcast_to(origins, dirs.shape)[:, k])) for k in range(3)))
    return model.scene.ray_intersect(mi.Ray3f(o, mi.Vector3f(*(mi.Float(np.ascontiguousarray(dirs[:, k])) for k in range(3)))))


def _view_rays(model, theta, ident: str, n: int):
    """n × n rays from the camera through a grid spanning the object's bounding sphere (perpendicular to the
    view): (camera, unit directions (n², 3), mask of rays whose first hit is the object)."""
    import mitsuba as mi

    model._apply(model.params.validate(theta))
    shape, cam = _shape(model, ident), _camera(model)
    lo, hi = (np.array(v, dtype=np.float64).ravel() for v in (shape.bbox().min, shape.bbox().max))
    c, r = (lo + hi) / 2, np.linalg.norm(hi - lo) / 2
    f = (c - cam) / np.linalg.norm(c - cam)
    a = np.cross(f, [0.0, 1.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(a, f)
    u, v = np.meshgrid(np.linspace(-r, r, n), np.linspace(-r, r, n))
    d = c + u.reshape(-1, 1) * a + v.reshape(-1, 1) * b - cam
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return cam, d, np.asarray(_cast(model, cam, d).shape == mi.ShapePtr(shape))


def visible_hits(model, theta, ident: str, n: int = 400) -> int:
    """Camera rays that see the object `ident` first: 0 means it is fully out of the line of sight."""
    return int(_view_rays(model, theta, ident, n)[2].sum())


def ball_visible_fraction(model, theta, n: int = 300) -> float:
    """Visible fraction of the ball's silhouette: rays seeing the ball / rays that meet the sphere."""
    cam, d, seen = _view_rays(model, theta, "ball", n)
    c, r = ball_centre(model, theta), model.params.validate(theta)[1]
    oc = cam - c
    meets = (d @ oc) ** 2 - (oc @ oc - r * r) > 0
    return float(seen.sum() / meets.sum())


def ball_centre(model, theta) -> np.ndarray:
    model._apply(model.params.validate(theta))
    return np.array(model._params["ball.to_world"].matrix, dtype=np.float64).reshape(4, 4)[:3, 3]


# -- hallway + room ---------------------------------------------------------------------------------
def test_hallway_loads_renders_and_both_parameters_move_the_ball(hallway):
    assert hallway.params.names == ("ball_location", "ball_radius")
    base = hallway.render([point(100), 0.10], 16, 0)
    assert base.shape == (64, 32, 3) and bool(np.isfinite(base.numpy()).all()) and float(base.mean()) > 0
    for theta in ([point(150), 0.10], [point(100), 0.15]):  # moved 50 cm down the hallway; grown to 15 cm
        change = (hallway.render(theta, 16, 0) - base).abs()  # same seed: the change is the ball's
        per_channel = change.sum(dim=(0, 1))
        assert float(change.max()) > 0.03 and per_channel[0] > 1.5 * per_channel[2], per_channel  # a red ball


def test_hallway_path_has_860_points_1cm_apart(hallway):
    p = hallway.params
    assert p.lower[0] == 0.0 and p.upper[0] == pytest.approx(8.59)
    grid = np.linspace(p.lower[0], p.upper[0], 860)
    assert np.allclose(np.diff(grid), 0.01)
    # through the scene: the ball's centre moves 1 cm per point on a straight leg; the path's corners
    # (turn into the doorway, turn towards the room's back wall) cut at most a chord, never more
    centres = np.array([ball_centre(hallway, [point(k), 0.10]) for k in (1, 2, 100, 101, 260, 261, 427, 428, 859, 860)])
    steps = np.linalg.norm(centres[1::2] - centres[::2], axis=1)
    assert np.allclose(steps, 0.01, atol=1e-6), steps
    assert np.allclose(centres[:, 1], centres[0, 1])  # constant height


def test_hallway_point_427_is_the_rooms_left_to_right_midpoint(hallway):
    c = ball_centre(hallway, [point(427), 0.10])
    ball_centre(hallway, [point(1), 0.10])  # move the ball away so the rays see the walls
    beside_door = c + [0.0, 0.0, -0.6]  # the path crosses the room on the door's axis; look beside it
    hits = _cast(hallway, beside_door, np.array([[-1.0, 0, 0], [1.0, 0, 0]]))
    left, right = np.asarray(hits.t, dtype=np.float64)
    assert abs(left - right) < 0.01 and left + right == pytest.approx(3.3274, abs=1e-3)


def test_hallway_los_ends_between_points_260_and_261(hallway):
    for k in (1, 100, 200, 250, 260):
        assert visible_hits(hallway, [point(k), 0.10], "ball") > 0, k
    for k in (261, 300, 427, 600, 860):
        assert visible_hits(hallway, [point(k), 0.10], "ball") == 0, k


def test_hallway_ball_is_whole_in_view_up_to_point_240(hallway):
    """The paper's position (3), the last point with the whole ball in view: here 240 (ray casting at
    0.7 mm spacing; the 1e-3 slack is the grid's edge quantisation)."""
    for k in (1, 190, 240):
        assert ball_visible_fraction(hallway, [point(k), 0.10]) > 0.999, k
    assert ball_visible_fraction(hallway, [point(241), 0.10]) < 0.995
    assert 0.3 < ball_visible_fraction(hallway, [point(250), 0.10]) < 0.7  # half hidden: between (3) and (4)


def test_hallway_moving_the_ball_changes_the_image_far_more_in_los_than_in_nlos(hallway):
    def change(k):  # move the ball 5 cm (common random numbers: same seed)
        return float((hallway.render([point(k + 5), 0.10], 32, 3) - hallway.render([point(k), 0.10], 32, 3)).abs().sum())

    # at this size few sample paths reach a ball in the room, so the NLOS change is often exactly 0
    los, nlos = change(100), change(500)
    assert los > 0.1 and los > 20 * nlos, (los, nlos)


def test_hallway_files_are_what_the_generator_writes():
    """scenes/hallway_room.{xml,yaml} equal the output of scripts/make_hallway_path.py (edit the script, not
    the generated files: a hand edit would be lost on the next regeneration)."""
    import importlib.util
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    spec = importlib.util.spec_from_file_location("make_hallway_path", root / "scripts" / "make_hallway_path.py")
    gen = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(gen)
    g = gen.layout()
    assert (root / "scenes" / "hallway_room.xml").read_text() == gen.scene_xml(g)
    assert (root / "scenes" / "hallway_room.yaml").read_text() == gen.spec_yaml(g)


# -- Π hallway ---------------------------------------------------------------------------------------
def test_pi_hallway_loads_renders_and_the_object_slides(pi):
    assert pi.params.names == ("object_position",)
    a, b = pi.render([0.7], 16, 0), pi.render([0.8], 16, 0)
    assert a.shape == (30, 40, 3) and bool(np.isfinite(a.numpy()).all())
    # sliding 10 cm behind the corner hides part of the red object and uncovers grey floor and wall
    # (same seed): red falls while green and blue rise
    d = (a - b).sum(dim=(0, 1))
    assert d[0] > 0 and d[1] < 0 and d[2] < 0, d


def test_pi_hallway_object_leaves_the_line_of_sight_near_0_9_m(pi):
    for t in (0.7, 0.8, 0.85):
        assert visible_hits(pi, [t], "object", 200) > 0, t
    for t in (0.9, 1.2, 1.69):
        assert visible_hits(pi, [t], "object", 200) == 0, t


def test_pi_hallway_image_change_is_far_larger_in_los(pi):
    def change(t):
        return float((pi.render([t + 0.05], 64, 1) - pi.render([t], 64, 1)).abs().sum())

    # seeds 0–9 at these settings: LOS/NLOS ratio 7.2–16
    assert change(0.7) > 5 * change(1.3)
