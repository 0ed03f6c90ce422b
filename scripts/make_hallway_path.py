"""Generate scenes/hallway_room.xml and scenes/hallway_room.yaml: the paper's real hallway + room, the
camera 1.5108 m outside the hallway, and the red ball's 860-point path (1 cm steps).

Run from the project root: `python scripts/make_hallway_path.py` (rewrites both files; edit this script,
not the generated files). Frame: metres, y up, the hallway runs from its entrance at z = 0 towards −z,
x to the right as seen by the camera. Imperial values (the building's) are noted in inches.

Given by the paper: hallway length 4.9784, room 3.3274 (x) × 3.3782 (z), height 2.4384, lights and
window (sizes, radiances), camera 1.5108 m outside the hallway, roughplastic α (walls 0.12, ceiling
0.28, trim 0.08, floor 0.07; IOR 1.5), ball r = 10 cm on an 860-point, 1 cm path: LOS down the
hallway, LOS → NLOS at points 260 → 261 in the doorway, then across the room (left → right, then
front → back); point 427 at the room's left-to-right midpoint.

Chosen here (the text lacks them): hallway width 48 in, door 30 × 80 in near the hallway's back
end (its far jamb 6 in from the back wall), door casing 2.5 × 0.75 in and baseboards 3.5 × 0.5 in
(trim), a closed 5 × 3 m lobby around the camera, camera 1.524 m high and 4 in left of the right
wall's plane (so, as in the paper's viewpoint study, a shift of ≈ +10 cm makes it parallel to that
wall), aimed at a point on the back wall; light positions; the window on the room's right wall with
a 36 in sill; uniform colours (no wood texture). Two values are *solved* so that the paper's path
facts hold exactly: the wall thickness between hallway and room (the ball leaves the line of sight
between points 260 and 261, at arc length 2.595 m) and the start of the path (point 427 at the
room's midpoint). Path vertices: P0 start mid-hallway → P1 turn at the door → P2 inside the room near
its right wall → P3 near its back wall; arc length 8.59 m, so θ = 0, 0.01, …, 8.59 are the 860 points.
"""
from __future__ import annotations

import math
from pathlib import Path

IN = 0.0254
# -- given -------------------------------------------------------------------------------------
HALL_LEN, ROOM_X, ROOM_Z, HEIGHT = 4.9784, 3.3274, 3.3782, 2.4384
CAM_OUTSIDE = 1.5108
BALL_R, STEP, N_POINTS, LOS_LAST, MID_POINT = 0.10, 0.01, 860, 260, 427
# -- chosen ------------------------------------------------------------------------------------
HALL_W = 48 * IN
DOOR_W, DOOR_H = 30 * IN, 80 * IN
DOOR_FAR_JAMB_FROM_BACK = 6 * IN
DOOR_TO_ROOM_CORNER = 2 * IN          # room front wall to the door's near jamb
CASING_W, CASING_T = 2.5 * IN, 0.75 * IN
BASE_H, BASE_T = 3.5 * IN, 0.5 * IN
LOBBY_HALF_W, LOBBY_DEPTH, SLAB = 2.5, 3.0, 0.05
CAM_Y, CAM_FROM_RIGHT_WALL = 1.524, 4 * IN
CAM_TARGET = (0.0, 1.0, -HALL_LEN)    # a point on the hallway's back wall
FOV_X = 45.0
BALL_Y = 0.16                         # ball centre height: a 15 cm ball (radius study) clears the floor
WALL_CLEARANCE = 0.13                 # path to room walls (ball radius + 3 cm)
WINDOW_W, WINDOW_H, WINDOW_SILL = 54 * IN, 45.5 * IN, 36 * IN
HALL_LIGHTS = [(-60 * IN, 1.75 * IN, 102.6), (-100 * IN, 1.75 * IN, 102.6),
               (-140 * IN, 1.25 * IN, 151.0), (-180 * IN, 1.25 * IN, 151.0)]  # (z, radius, radiance)
ROOM_LIGHT_R, ROOM_LIGHT_L, WINDOW_L = 8 * IN, 18.5, 20.0


def layout() -> dict:
    """All derived positions (metres)."""
    zb = -HALL_LEN
    z_door = zb + DOOR_FAR_JAMB_FROM_BACK + DOOR_W / 2
    cam = (HALL_W / 2 - CAM_FROM_RIGHT_WALL, CAM_Y, CAM_OUTSIDE)
    # the occluding edge: the casing's corner at the door's near jamb, protruding into the hallway
    edge = (HALL_W / 2 - CASING_T, z_door + DOOR_W / 2)
    # the vertical plane through the camera and that edge; the ball (at the door's centre line) is just
    # out of sight when its centre lies BALL_R beyond it: x_b = x_line(z_door) + BALL_R / cos(angle)
    dx, dz = edge[0] - cam[0], edge[1] - cam[2]
    x_line = edge[0] + dx / dz * (z_door - edge[1])
    x_hidden = x_line + BALL_R * math.hypot(dx, dz) / abs(dz)
    s_hidden = (LOS_LAST - 0.5) * STEP  # between point 260 (arc 2.59) and 261 (arc 2.60)
    s_mid = (MID_POINT - 1) * STEP
    # arc(x) = L1 + x along the room leg: L1 + x_hidden = s_hidden and L1 + x_mid = s_mid, with
    # x_mid = HALL_W/2 + t + ROOM_X/2 → solve t (wall thickness) and L1 (first leg)
    t = s_mid - s_hidden + x_hidden - HALL_W / 2 - ROOM_X / 2
    if not 0.05 < t < 0.2:
        raise ValueError(f"solved wall thickness {t:.4f} m is implausible; revisit the chosen layout")
    x_room0 = HALL_W / 2 + t
    x_room1 = x_room0 + ROOM_X
    L1 = s_hidden - x_hidden
    z_room_front = z_door + DOOR_W / 2 + DOOR_TO_ROOM_CORNER
    z_room_back = z_room_front - ROOM_Z
    x2 = x_room1 - WALL_CLEARANCE
    length = (N_POINTS - 1) * STEP
    L3 = length - L1 - x2
    z3 = z_door - L3
    if z3 < z_room_back + WALL_CLEARANCE - 1e-9:
        raise ValueError(f"the path's last leg ends {z_room_back + WALL_CLEARANCE - z3:.3f} m inside the back wall")
    path = [(0.0, BALL_Y, z_door + L1), (0.0, BALL_Y, z_door), (x2, BALL_Y, z_door), (x2, BALL_Y, z3)]
    return dict(zb=zb, z_door=z_door, cam=cam, edge=edge, t=t, x_room0=x_room0, x_room1=x_room1,
                z_room_front=z_room_front, z_room_back=z_room_back, path=path, length=length, L1=L1)


def _f(v: float) -> str:
    return f"{v:.6g}"


def _box(ident: str, lo, hi, bsdf: str) -> str:
    c = [(a + b) / 2 for a, b in zip(lo, hi, strict=True)]
    h = [(b - a) / 2 for a, b in zip(lo, hi, strict=True)]
    return (f'    <shape type="cube" id="{ident}"><transform name="to_world">'
            f'<scale x="{_f(h[0])}" y="{_f(h[1])}" z="{_f(h[2])}"/>'
            f'<translate x="{_f(c[0])}" y="{_f(c[1])}" z="{_f(c[2])}"/></transform><ref id="{bsdf}"/></shape>')


def _disk_light(ident: str, x: float, z: float, r: float, radiance: float) -> str:
    return (f'    <shape type="disk" id="{ident}"><transform name="to_world"><scale value="{_f(r)}"/>'
            f'<rotate x="1" angle="90"/><translate x="{_f(x)}" y="{_f(HEIGHT - 0.002)}" z="{_f(z)}"/></transform>'
            f'<ref id="black"/><emitter type="area"><rgb name="radiance" value="{_f(radiance)}"/></emitter></shape>')


def scene_xml(g: dict) -> str:
    w2, t, H, zb, zd = HALL_W / 2, g["t"], HEIGHT, g["zb"], g["z_door"]
    xr0, xr1, zf, zk = g["x_room0"], g["x_room1"], g["z_room_front"], g["z_room_back"]
    d0, d1 = zd - DOOR_W / 2, zd + DOOR_W / 2
    x_min, x_max = -LOBBY_HALF_W - t, xr1 + t
    z_min, z_max = zk - t, LOBBY_DEPTH + t
    boxes = [
        ("floor", (x_min, -SLAB, z_min), (x_max, 0, z_max), "floor_bsdf"),
        ("ceiling", (x_min, H, z_min), (x_max, H + SLAB, z_max), "ceiling_bsdf"),
        # hallway
        ("hall_left", (-w2 - t, 0, zb - t), (-w2, H, 0), "wall"),
        ("hall_back", (-w2 - t, 0, zb - t), (w2, H, zb), "wall"),
        ("hall_right_near", (w2, 0, d1), (w2 + t, H, 0), "wall"),
        ("hall_right_far", (w2, 0, zk - t), (w2 + t, H, d0), "wall"),
        ("door_header", (w2, DOOR_H, d0), (w2 + t, H, d1), "wall"),
        # room (its left wall is the hallway's right wall)
        ("room_front", (xr0, 0, zf), (x_max, H, zf + t), "wall"),
        ("room_back", (xr0, 0, z_min), (x_max, H, zk), "wall"),
        ("room_right", (xr1, 0, z_min), (x_max, H, zf + t), "wall"),
        # lobby around the camera, entered from the hallway's mouth at z = 0
        ("lobby_front_left", (-LOBBY_HALF_W, 0, -t), (-w2 - t, H, 0), "wall"),
        ("lobby_front_right", (w2 + t, 0, -t), (LOBBY_HALF_W, H, 0), "wall"),
        ("lobby_left", (-LOBBY_HALF_W - t, 0, -t), (-LOBBY_HALF_W, H, LOBBY_DEPTH), "wall"),
        ("lobby_right", (LOBBY_HALF_W, 0, -t), (LOBBY_HALF_W + t, H, LOBBY_DEPTH), "wall"),
        ("lobby_back", (-LOBBY_HALF_W - t, 0, LOBBY_DEPTH), (LOBBY_HALF_W + t, H, LOBBY_DEPTH + t), "wall"),
        # door casing on the hallway side (its corner at the near jamb is the LOS edge)
        ("casing_near", (w2 - CASING_T, 0, d1), (w2, DOOR_H + CASING_W, d1 + CASING_W), "trim"),
        ("casing_far", (w2 - CASING_T, 0, d0 - CASING_W), (w2, DOOR_H + CASING_W, d0), "trim"),
        ("casing_head", (w2 - CASING_T, DOOR_H, d0), (w2, DOOR_H + CASING_W, d1), "trim"),
        # baseboards
        ("base_hall_left", (-w2, 0, zb), (-w2 + BASE_T, BASE_H, 0), "trim"),
        ("base_hall_back", (-w2 + BASE_T, 0, zb), (w2, BASE_H, zb + BASE_T), "trim"),
        ("base_hall_right_near", (w2 - BASE_T, 0, d1 + CASING_W), (w2, BASE_H, 0), "trim"),
        ("base_hall_right_far", (w2 - BASE_T, 0, zb + BASE_T), (w2, BASE_H, d0 - CASING_W), "trim"),
        ("base_room_left_near", (xr0, 0, d1), (xr0 + BASE_T, BASE_H, zf), "trim"),
        ("base_room_left_far", (xr0, 0, zk), (xr0 + BASE_T, BASE_H, d0), "trim"),
        ("base_room_front", (xr0 + BASE_T, 0, zf - BASE_T), (xr1, BASE_H, zf), "trim"),
        ("base_room_back", (xr0 + BASE_T, 0, zk), (xr1, BASE_H, zk + BASE_T), "trim"),
        ("base_room_right", (xr1 - BASE_T, 0, zk + BASE_T), (xr1, BASE_H, zf - BASE_T), "trim"),
    ]
    room_zc = (zf + zk) / 2
    cam, tgt = g["cam"], CAM_TARGET
    p_def = g["path"][0]
    lines = [
        "<!-- GENERATED by scripts/make_hallway_path.py: edit that script (it documents every dimension), not this file.",
        "     hallway_room: the paper's real hallway (4.9784 m) + room (3.3274 × 3.3782 m), 2.4384 m tall, seen from a",
        f"     camera {CAM_OUTSIDE} m outside the hallway; a red ball (r = 10 cm) moves on an 860-point path (see the .yaml).",
        f"     Frame: metres, y up, hallway from z = 0 to z = {_f(zb)}, x to the right. Solved wall thickness hallway|room:",
        f"     {_f(t)} m; door centre z = {_f(zd)}; room x ∈ [{_f(xr0)}, {_f(xr1)}], z ∈ [{_f(zk)}, {_f(zf)}].",
        "     Paper scale: 256 × 512 (width × height, portrait like the phone photo); tests pass smaller width/height. -->",
        '<scene version="3.0.0">',
        '    <default name="width" value="256"/>',
        '    <default name="height" value="512"/>',
        '    <default name="max_depth" value="8"/>',
        '    <default name="spp" value="16"/>',
        '    <integrator type="path"><integer name="max_depth" value="$max_depth"/></integrator>',
        '    <sensor type="perspective" id="camera">',
        f'        <float name="fov" value="{FOV_X}"/><string name="fov_axis" value="x"/>',
        '        <transform name="to_world">',
        f'            <lookat origin="{", ".join(map(_f, cam))}" target="{", ".join(map(_f, tgt))}" up="0, 1, 0"/>',
        "        </transform>",
        '        <sampler type="independent"><integer name="sample_count" value="$spp"/></sampler>',
        '        <film type="hdrfilm"><integer name="width" value="$width"/><integer name="height" value="$height"/>',
        '            <string name="pixel_format" value="rgb"/><rfilter type="box"/></film>',
        "    </sensor>",
        "",
        "    <!-- roughplastic, IOR 1.5 inside / 1.0 outside; walls a neutral grey (the paper keeps RGB channels equal) -->",
        '    <bsdf type="roughplastic" id="wall"><float name="alpha" value="0.12"/><float name="int_ior" value="1.5"/>'
        '<float name="ext_ior" value="1.0"/><rgb name="diffuse_reflectance" value="0.65, 0.65, 0.65"/></bsdf>',
        '    <bsdf type="roughplastic" id="ceiling_bsdf"><float name="alpha" value="0.28"/><float name="int_ior" value="1.5"/>'
        '<float name="ext_ior" value="1.0"/><rgb name="diffuse_reflectance" value="0.84, 0.83, 0.80"/></bsdf>',
        '    <bsdf type="roughplastic" id="trim"><float name="alpha" value="0.08"/><float name="int_ior" value="1.5"/>'
        '<float name="ext_ior" value="1.0"/><rgb name="diffuse_reflectance" value="0.80, 0.79, 0.76"/></bsdf>',
        "    <!-- floor: clear textured vinyl over wood; the wood-grain texture is replaced by its mean colour -->",
        '    <bsdf type="roughplastic" id="floor_bsdf"><float name="alpha" value="0.07"/><float name="int_ior" value="1.5"/>'
        '<float name="ext_ior" value="1.0"/><rgb name="diffuse_reflectance" value="0.42, 0.29, 0.18"/></bsdf>',
        '    <bsdf type="diffuse" id="black"><rgb name="reflectance" value="0"/></bsdf>',
        "",
        *[_box(*b) for b in boxes],
        "",
        "    <!-- hallway ceiling lights (disks facing down): two r = 1.75 in at 102.6, two r = 1.25 in at 151 W/(sr m²) -->",
        *[_disk_light(f"hall_light_{i}", 0.0, z, r, L) for i, (z, r, L) in enumerate(HALL_LIGHTS)],
        "    <!-- room ceiling light r = 8 in at 18.5; window 54 × 45.5 in at 20 on the room's right wall (sill 36 in) -->",
        _disk_light("room_light", (xr0 + xr1) / 2, room_zc, ROOM_LIGHT_R, ROOM_LIGHT_L),
        f'    <shape type="rectangle" id="window"><transform name="to_world">'
        f'<scale x="{_f(WINDOW_W / 2)}" y="{_f(WINDOW_H / 2)}"/><rotate y="1" angle="-90"/>'
        f'<translate x="{_f(xr1 - 0.002)}" y="{_f(WINDOW_SILL + WINDOW_H / 2)}" z="{_f(room_zc)}"/></transform>'
        f'<ref id="black"/><emitter type="area"><rgb name="radiance" value="{_f(WINDOW_L)}"/></emitter></shape>',
        "",
        "    <!-- the red ball (its position and radius are θ: see hallway_room.yaml); placed at path point 1 -->",
        f'    <shape type="sphere" id="ball"><point name="center" x="{_f(p_def[0])}" y="{_f(p_def[1])}" z="{_f(p_def[2])}"/>'
        f'<float name="radius" value="{_f(BALL_R)}"/>',
        '        <bsdf type="roughplastic" id="ball_bsdf"><float name="alpha" value="0.4862"/><float name="int_ior" value="1.5"/>'
        '<rgb name="diffuse_reflectance" value="0.8, 0.05, 0.05"/></bsdf></shape>',
        "</scene>",
        "",
    ]
    return "\n".join(lines)


def spec_yaml(g: dict) -> str:
    pts = ", ".join("[" + ", ".join(f"{v:.9g}" for v in p) + "]" for p in g["path"])
    s260, s261, s427 = (LOS_LAST - 1) * STEP, LOS_LAST * STEP, (MID_POINT - 1) * STEP
    return f"""# GENERATED by scripts/make_hallway_path.py (edit the script, not this file).
# hallway_room: the paper's real hallway + room with a red ball; θ = (ball_location, ball_radius).
# ball_location is the arc length (m) along the path: point k of the paper's 860 points (k = 1..860,
# 1 cm apart) is θ = (k − 1)·0.01 m, i.e. a grid {{start: 0, stop: {_f(g["length"])}, num: {N_POINTS}}}.
# Paper's marked positions: (3) point 240 (θ = 2.39), the last with the whole ball in view; point 250
# (θ = 2.49) half hidden, between (3) and (4); (4) point 261 (θ = {s261:.2f}), the first fully hidden by
# the door casing, right after point 260 (θ = {s260:.2f}), the last with any of it in view; (5) point 427
# (θ = {s427:.2f}), the room's left-to-right midpoint (radius study). Checked by ray casting in tests.
# Path: start mid-hallway → turn at the door → room near its right wall → back wall.
file: hallway_room.xml
description: real hallway + room (paper, section 3), red ball on an 860-point 1 cm path; 256×512 at paper scale
smoke: {{defines: {{width: 8, height: 16, max_depth: 4}}}}    # `nlosbench run --smoke`: a seconds-long run
params:
  - name: ball_location
    kind: path
    object: ball
    points: [{pts}]
    lower: 0.0
    upper: {_f(g["length"])}
    default: {s260:.2f}
    units: m
    description: arc length along the 860-point path (point k at (k-1)*0.01 m); LOS up to {s260:.2f}, NLOS from {s261:.2f}
  - name: ball_radius
    kind: radius
    object: ball
    lower: 0.01
    upper: 0.15
    default: {_f(BALL_R)}
    units: m
    description: ball radius (paper's radius study 1-15 cm at point 427, θ_location = {s427:.2f} m)
"""


def main() -> None:
    g = layout()
    scenes = Path(__file__).resolve().parents[1] / "scenes"
    (scenes / "hallway_room.xml").write_text(scene_xml(g))
    (scenes / "hallway_room.yaml").write_text(spec_yaml(g))
    print(
        f"wall thickness {g['t']:.4f} m, first leg {g['L1']:.4f} m, camera x {g['cam'][0]:.4f} m, "
        f"path {[tuple(round(v, 4) for v in p) for p in g['path']]}"
    )


if __name__ == "__main__":
    main()
