"""The SegGraspSet twin: 12 categories, 36 objects, each a set of named parts built from solid primitives.

The first nine categories have two or three parts; scissors, kettles and eyeglasses (`assets.multipart`) have
three or four, some of them thin (a pivot screw, a gooseneck spout, a nose bridge, temples).

A category builder takes a parameter dict (lengths in metres) and returns its parts in prompt order plus "keep
open" probe points: places (a mug handle's hole, a cup's cavity) that the collision model must leave empty. Every
object is built in its resting pose on a table (z up); `assets.generate` moves the footprint centre to the origin
and the lowest point to z = 0.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import manifold3d as mf
import numpy as np

from assets.multipart import build_glasses, build_kettle, build_scissors
from assets.shapes import (
    Built,
    box,
    cylinder,
    ellipse,
    extrude,
    lobed_circle,
    loft,
    loft_along_x,
    revolve,
    rounded_polyline,
    superellipse,
    sweep,
)

@dataclass(frozen=True)
class Material:
    """Bulk density (kg/m^3) and Coulomb friction coefficient of a part's material."""

    name: str
    density: float
    friction: float


MATERIALS = {
    m.name: m
    for m in (
        Material("ceramic", 2000.0, 0.6),
        Material("steel", 7850.0, 0.45),
        Material("wood", 700.0, 0.6),
        Material("plastic", 1100.0, 0.5),
        Material("rubber_grip", 1150.0, 0.9),
        Material("nylon", 1150.0, 0.45),
        Material("silicone", 1200.0, 0.8),
        Material("aluminium", 2700.0, 0.45),
        Material("bakelite", 1350.0, 0.55),
        Material("glass", 2500.0, 0.45),
        Material("rubber", 1200.0, 0.9),
        # Closed bottles are modelled as solids; their density is the bulk density of container plus contents.
        Material("pet_bottle_bulk", 300.0, 0.45),
        Material("glass_bottle_bulk", 380.0, 0.45),
        Material("jar_bulk", 450.0, 0.5),
        Material("hdpe_cap", 950.0, 0.6),
        Material("tin_cap", 7850.0, 0.5),
        # An empty kettle is a 0.6-0.8 mm stainless shell with a thicker base around air (its body is modelled as
        # a solid); its pressed lid and hollow spout likewise.
        Material("kettle_bulk", 300.0, 0.45),
        Material("steel_lid_bulk", 600.0, 0.45),
        Material("steel_tube_bulk", 2400.0, 0.45),
        Material("acetate", 1300.0, 0.5),
    )
}


@dataclass(frozen=True)
class ObjectSpec:
    """One object of the set: its id, category, builder parameters and a material per part (prompt order)."""

    object_id: str
    category: str
    params: dict[str, float | str | list] = field(default_factory=dict)  # a list: corner points (kettle spout)
    materials: tuple[str, ...] = ()


def _ring_circle(radius: float, n: int) -> np.ndarray:
    return ellipse(radius, radius, n)


# ----------------------------------------------------------------------------------------------------------- mug
def build_mug(p: dict) -> Built:
    """Mug: revolved ceramic body (optionally tapered, chamfered foot, rounded rim) + a ring or D-shaped handle."""
    r_bottom, r_top, height = p["radius_bottom"], p["radius_top"], p["height"]
    wall, floor = p["wall"], p["floor"]
    chamfer = p["foot_chamfer"]

    def r_out(z: float) -> float:
        return r_bottom + (r_top - r_bottom) * z / height

    rim = [(r_top - wall / 2 + wall / 2 * np.cos(a), height - wall / 2 + wall / 2 * np.sin(a))
           for a in np.linspace(0.0, np.pi, 7)]
    fillet = [(r_out(floor) - wall - 0.006 + 0.006 * np.cos(a), floor + 0.006 + 0.006 * np.sin(a))
              for a in np.linspace(0.0, -np.pi / 2, 5)]
    profile = [(0.0, 0.0), (r_bottom - chamfer, 0.0), (r_bottom, chamfer), (r_out(height * 0.5), height * 0.5),
               *rim, (r_out(height * 0.5) - wall, height * 0.5), *fillet, (0.0, floor)]
    body = revolve(profile, int(p["segments"]), "mug body")

    z_top, z_bottom = p["handle_top"] * height, p["handle_bottom"] * height
    span = z_top - z_bottom
    thick, width = p["handle_thickness"], p["handle_width"]
    ring = p["handle_style"] == "ring"
    x_out = max(r_out(z_top), r_out(z_bottom)) + p["handle_reach"] + (0.5 * span if ring else 0.0)
    corner = 0.5 * span if ring else p["handle_corner"] * span
    path = rounded_polyline(
        [(r_out(z_top) - wall / 2, 0, z_top), (x_out, 0, z_top), (x_out, 0, z_bottom), (r_out(z_bottom) - wall / 2, 0, z_bottom)],
        [corner, corner], step=0.003,
    )

    def section(t: float) -> np.ndarray:
        swell = 1.0 + p["handle_swell"] * np.sin(np.pi * t)
        return ellipse(width / 2 * swell, thick / 2, 20)

    handle = sweep(path, section, normal_hint=(0.0, 1.0, 0.0), what="mug handle")
    z_mid = 0.5 * (z_top + z_bottom)
    hole_centre = 0.5 * (r_out(z_mid) + x_out - thick / 2)
    return [("handle", handle), ("body", body)], [(hole_centre, 0.0, z_mid), (0.0, 0.0, 0.6 * height)]


# --------------------------------------------------------------------------------------------------------- knife
def build_knife(p: dict) -> Built:
    """Knife lying flat: bevel-ground blade (heel at x = 0, tip at +x) + a rounded handle along -x."""
    length, height = p["blade_length"], p["blade_height"]
    spine_t, edge_t = p["spine_thickness"], 0.0004
    tip_drop, edge_rise_start, spine_drop_start = p["tip_drop"], p["edge_rise_start"], p["spine_drop_start"]

    def spine_y(x: float) -> float:
        s = max(0.0, (x / length - spine_drop_start) / (1.0 - spine_drop_start))
        return -tip_drop * height * s ** p["spine_curve"]

    def edge_y(x: float) -> float:
        s = max(0.0, (x / length - edge_rise_start) / (1.0 - edge_rise_start))
        return -height + (height - tip_drop * height) * s ** p["edge_curve"]

    def blade_section(x: float) -> np.ndarray:
        ys, ye = spine_y(x), edge_y(x)
        ye = min(ye, ys - 0.0012)
        t = spine_t * (1.0 - 0.6 * (x / length) ** 2)
        yb = ye + 0.3 * (ys - ye)
        return np.array([(ys, t / 2), (ys, -t / 2), (yb, -0.6 * t / 2), (ye, -edge_t / 2), (ye, edge_t / 2), (yb, 0.6 * t / 2)])

    stations = np.concatenate([np.linspace(0.0, length * 0.9, 14), length * (0.9 + 0.1 * np.sqrt(np.linspace(0, 1, 8)[1:]))])
    stations[-1] = length * 0.998
    rings = [np.column_stack([np.full(6, x), blade_section(x)]) for x in stations]
    blade = loft(np.stack(rings), "knife blade")

    h_len, h_width, h_thick = p["handle_length"], p["handle_width"], p["handle_thickness"]
    centre_y = -h_width / 2 - p["handle_offset"]

    def handle_scale(x: float) -> float:
        s = -x / h_len  # 0 at the blade, 1 at the butt
        grip = 1.0 + p["handle_swell"] * np.sin(np.pi * min(s, 1.0))
        butt = np.sqrt(max(0.0, 1.0 - max(0.0, (s - 0.93) / 0.07) ** 2)) if s > 0.93 else 1.0
        return grip * max(butt, 0.55)

    handle = loft_along_x(
        np.concatenate([np.linspace(0.008, -h_len * 0.93, 18), -h_len * (0.93 + 0.07 * np.linspace(0, 1, 6)[1:])]),
        lambda x: superellipse(h_width / 2 * handle_scale(x), h_thick / 2 * handle_scale(x), p["handle_squareness"], 28),
        centre=lambda x: (centre_y, 0.0),
        what="knife handle",
    )
    return [("handle", handle), ("blade", blade)], []


# -------------------------------------------------------------------------------------------------------- hammer
def build_hammer(p: dict) -> Built:
    """Hammer lying on its side: tapered oval handle along +x, head across it (striking axis = y)."""
    length, width, thick = p["handle_length"], p["handle_width"], p["handle_thickness"]
    head_x = length - p["head_depth"] / 2

    def handle_scale(x: float) -> float:
        s = x / length
        flare = 1.0 + 0.12 * max(0.0, 1.0 - s / 0.08)
        neck = 1.0 - p["neck_taper"] * np.clip((s - 0.45) / 0.4, 0.0, 1.0)
        return flare * neck

    handle = loft_along_x(
        np.concatenate([[0.0, 0.002, 0.005], np.linspace(0.01, head_x + 0.3 * p["head_depth"] / 2, 26)]),
        lambda x: superellipse(width / 2 * handle_scale(x) * (0.75 if x < 0.001 else 1.0),
                               thick / 2 * handle_scale(x) * (0.75 if x < 0.001 else 1.0), 2.6, 28),
        what="hammer handle",
    )
    style, depth, hz = p["head_style"], p["head_depth"], p["head_height"]
    if style == "mallet":
        radius, half, bevel = p["face_radius"], p["head_length"] / 2, 0.004
        profile = [(0.0, -half), (radius - bevel, -half), (radius, -half + bevel), (radius, half - bevel),
                   (radius - bevel, half), (0.0, half)]
        head = revolve(profile, 40, "mallet head").rotate((90.0, 0.0, 0.0)).translate((head_x, 0.0, 0.0))
        return [("handle", handle), ("head", head)], []
    eye = box((depth, p["eye_length"], hz), (head_x, 0, 0))
    face_r = p["face_radius"]
    y0 = -p["eye_length"] / 2
    neck_len, face_len = p["face_neck"], 0.014
    head = eye + cylinder(face_r * 0.85, neck_len + 0.004, "y", (head_x, y0 - neck_len / 2 + 0.002, 0), 32)
    head = head + cylinder(face_r, face_len - 0.003, "y", (head_x, y0 - neck_len - face_len / 2 + 0.0015, 0), 32)
    head = head + cylinder(face_r, 0.003, "y", (head_x, y0 - neck_len - face_len + 0.0015, 0), 32, radius_end=face_r - 0.0022)
    y1 = p["eye_length"] / 2
    if style == "claw":
        bend = p["claw_bend"]
        angles = np.linspace(0.0, p["claw_angle"], 16)
        path = np.stack([head_x - bend + bend * np.cos(angles), y1 - 0.004 + bend * np.sin(angles), np.zeros_like(angles)], axis=1)

        def claw_section(t: float) -> np.ndarray:
            return superellipse(hz / 2 * (1.0 - 0.55 * t), depth / 2 * (1.0 - 0.7 * t), 3.0, 20)

        claw = sweep(path, claw_section, normal_hint=(0.0, 0.0, 1.0), what="hammer claw")
        tip, direction = path[-1], path[-1] - path[-2]
        direction /= np.linalg.norm(direction)
        slot_len = 0.6 * bend * p["claw_angle"]
        slot = box((slot_len + 0.02, 0.03, 0.0035)).rotate((0.0, 0.0, float(np.degrees(np.arctan2(direction[1], direction[0])))))
        slot = slot.translate(tuple(float(c) for c in tip - direction * (slot_len / 2 - 0.01)))
        head = head + (claw - slot)
    else:  # ball-peen
        head = head + cylinder(face_r * 0.75, p["peen_neck"] + 0.004, "y", (head_x, y1 + p["peen_neck"] / 2 - 0.002, 0), 32)
        head = head + mf.Manifold.sphere(p["peen_radius"], 32).translate((head_x, y1 + p["peen_neck"] + p["peen_radius"] * 0.6, 0))
    return [("handle", handle), ("head", head)], []


# --------------------------------------------------------------------------------------------------- screwdriver
def build_screwdriver(p: dict) -> Built:
    """Screwdriver lying down: fluted handle along +x (butt at 0), round shaft with a flat or cross tip."""
    h_len, radius = p["handle_length"], p["handle_radius"]

    def handle_radius(x: float) -> float:
        s = x / h_len
        butt = np.sqrt(max(0.0, 1.0 - max(0.0, (0.12 - s) / 0.12) ** 2)) * 0.35 + 0.65 if s < 0.12 else 1.0
        front = 1.0 - p["front_taper"] * np.clip((s - 0.7) / 0.3, 0.0, 1.0)
        return radius * butt * front

    stations = np.concatenate([np.linspace(0.0, 0.12 * h_len, 6), np.linspace(0.15 * h_len, h_len, 16)])
    handle = loft_along_x(stations, lambda x: lobed_circle(handle_radius(x), int(p["lobes"]), p["lobe_depth"], 48),
                          what="screwdriver handle")
    r_shaft, s_len = p["shaft_radius"], p["shaft_length"]
    x0, x_end = h_len - 0.02, h_len + s_len
    tip_len = p["tip_length"]

    def shaft_section(x: float) -> np.ndarray:
        s = np.clip((x - (x_end - tip_len)) / tip_len, 0.0, 1.0)
        if p["tip"] == "flat":
            return ellipse(r_shaft * (1.0 + 0.5 * s), r_shaft * (1.0 - 0.72 * s), 16)
        return _ring_circle(r_shaft * (1.0 - 0.7 * s), 16)

    shaft = loft_along_x(np.concatenate([np.linspace(x0, x_end - tip_len, 6), np.linspace(x_end - tip_len, x_end, 7)[1:]]),
                         shaft_section, what="screwdriver shaft")
    ferrule = cylinder(handle_radius(h_len) * 0.8, 0.012, "x", (h_len + 0.004, 0, 0), 32, radius_end=r_shaft * 1.4)
    return [("handle", handle + ferrule), ("shaft", shaft)], []


# ------------------------------------------------------------------------------------------------------- spatula
def build_spatula(p: dict) -> Built:
    """Spatula / turner: flat blade on the table (+x), angled neck, handle sloping up from its butt on the table."""
    h_len, h_width, h_thick = p["handle_length"], p["handle_width"], p["handle_thickness"]
    lift = p["handle_lift"]
    t_blade, b_len, b_width = p["blade_thickness"], p["blade_length"], p["blade_width"]

    def centre(x: float) -> tuple[float, float]:
        return 0.0, h_thick / 2 + lift * x / h_len

    def scale(x: float) -> float:
        s = x / h_len
        return (0.8 + 0.2 * np.sqrt(min(1.0, s / 0.05))) * (1.0 - 0.25 * np.clip((s - 0.75) / 0.25, 0.0, 1.0))

    handle = loft_along_x(np.linspace(0.0, h_len, 22),
                          lambda x: superellipse(h_width / 2 * scale(x), h_thick / 2 * scale(x), 2.5, 28),
                          centre, "spatula handle")
    z_front = centre(h_len)[1]
    neck_len = p["neck_length"]
    x_blade = h_len + neck_len
    path = rounded_polyline([(h_len - 0.02, 0, centre(h_len - 0.02)[1]), (h_len + 0.01, 0, z_front),
                             (x_blade - 0.01, 0, t_blade / 2 + 0.0005), (x_blade + 0.012, 0, t_blade / 2 + 0.0005)],
                            [0.03, 0.03], step=0.003)
    neck = sweep(path, lambda t: superellipse(p["neck_width"] / 2 * (1 + 0.6 * t), p["neck_thickness"] / 2, 4.0, 20),
                 normal_hint=(0.0, 1.0, 0.0), what="spatula neck")
    outline = superellipse(b_len / 2, b_width / 2, p["blade_squareness"], 64)
    blade = extrude(outline, t_blade, "spatula blade").translate((x_blade + b_len / 2, 0.0, 0.0))
    for k in range(int(p["slots"])):
        y = (k - (p["slots"] - 1) / 2) * b_width / (p["slots"] + 1)
        blade = blade - box((0.55 * b_len, 0.005, 0.01), (x_blade + 0.45 * b_len, y, 0.0))
    return [("handle", handle), ("blade", blade + neck)], []


# -------------------------------------------------------------------------------------------------------- bottle
def build_bottle(p: dict) -> Built:
    """Bottle: revolved body (chamfered base, shoulder, neck with a support ring under a screw cap; a crown-capped
    glass bottle has none) + a ridged screw or crown cap."""
    radius, height = p["radius"], p["height"]
    r_neck, shoulder, neck_top = p["neck_radius"], p["shoulder_start"] * height, height
    n = int(p["segments"])
    curve = [(r_neck + (radius - r_neck) * (0.5 + 0.5 * np.cos(np.pi * s)), shoulder + (p["neck_start"] * height - shoulder) * s)
             for s in np.linspace(0.0, 1.0, 10)]
    ring = []
    if p["support_ring"]:
        ring_z = p["ring_height"] * height
        ring = [(r_neck, ring_z - 0.002), (r_neck + 0.0025, ring_z - 0.001), (r_neck + 0.0025, ring_z + 0.001),
                (r_neck, ring_z + 0.002)]
    profile = [(0.0, 0.0), (radius - 0.004, 0.0), (radius, 0.004), (radius, shoulder), *curve[1:], *ring,
               (r_neck, neck_top), (0.0, neck_top)]
    body = revolve(profile, n, "bottle body")
    cap_r, cap_h = p["cap_radius"], p["cap_height"]
    cap_bottom = neck_top - cap_h + 0.003
    cap = extrude(lobed_circle(cap_r, int(p["cap_ridges"]), 0.05, int(p["cap_ridges"]) * 4), cap_h, "bottle cap")
    bevel = cylinder(cap_r * 1.2, cap_h, "z", (0, 0, cap_h / 2), n, radius_end=cap_r * 0.93)
    cap = (cap ^ bevel).translate((0.0, 0.0, cap_bottom))
    return [("cap", cap), ("body", body)], []


# --------------------------------------------------------------------------------------------------- frying pan
def build_frying_pan(p: dict) -> Built:
    """Frying pan: revolved aluminium shell with flared wall and rim, a bracket, and a rising handle along +x."""
    r_bottom, r_top, height, wall = p["radius_bottom"], p["radius_top"], p["height"], p["wall"]
    n = int(p["segments"])

    def r_out(z: float) -> float:
        return r_bottom + (r_top - r_bottom) * z / height

    fillet_r = 0.012
    outer_fillet = [(r_bottom - fillet_r + fillet_r * np.sin(a), fillet_r - fillet_r * np.cos(a)) for a in np.linspace(0, np.pi / 2.6, 5)]
    rim = [(r_top - wall / 2 + wall / 2 * np.cos(a), height + wall / 2 * np.sin(a)) for a in np.linspace(0, np.pi, 6)]
    inner_fillet = [(r_bottom - fillet_r + (fillet_r - wall) * np.sin(a), fillet_r - (fillet_r - wall) * np.cos(a))
                    for a in np.linspace(np.pi / 2.6, 0, 5)]
    profile = [(0.0, 0.0), *outer_fillet, (r_out(height * 0.5), height * 0.5), *rim,
               (r_out(height * 0.5) - wall, height * 0.5), *inner_fillet, (0.0, wall)]
    pan = revolve(profile, n, "pan shell")
    cavity = revolve([(0.0, wall), (r_bottom - wall, wall), (r_top - wall, height), (r_top + 0.02, height + 0.05),
                      (0.0, height + 0.05)], n, "pan cavity")
    z_handle = p["handle_height"] * height
    lug_x = r_out(z_handle)
    lug = box((0.03, p["handle_width"] * 1.15, p["handle_thickness"] * 1.4), (lug_x, 0.0, z_handle)) - cavity
    pan = pan + lug
    h_len, h_width, h_thick = p["handle_length"], p["handle_width"], p["handle_thickness"]
    rise = np.tan(np.radians(p["handle_angle"]))
    x0 = lug_x + 0.005

    def centre(x: float) -> tuple[float, float]:
        return 0.0, z_handle + rise * (x - x0)

    def scale(x: float) -> float:
        s = (x - x0) / h_len
        end = np.sqrt(max(0.0, 1.0 - max(0.0, (s - 0.94) / 0.06) ** 2)) * 0.4 + 0.6 if s > 0.94 else 1.0
        return (0.8 + 0.35 * s) * end

    handle = loft_along_x(np.linspace(x0, x0 + h_len, 26),
                          lambda x: superellipse(h_width / 2 * scale(x), h_thick / 2 * (0.9 + 0.1 * scale(x)), 3.0, 28),
                          centre, "pan handle")
    hole_x = x0 + h_len - 0.022
    handle = handle - cylinder(0.0055, 0.06, "z", (hole_x, 0.0, centre(hole_x)[1]), 24)
    return [("handle", handle), ("pan", pan)], [(0.0, 0.0, height * 0.6)]


# --------------------------------------------------------------------------------------------------- toothbrush
def build_toothbrush(p: dict) -> Built:
    """Toothbrush lying on its back: handle along +x (optionally bowed), head plate with a bristle block on top."""
    h_len, width, thick = p["handle_length"], p["handle_width"], p["handle_thickness"]
    bow = p["bow"]

    def centre(x: float) -> tuple[float, float]:
        return 0.0, thick / 2 + bow * np.sin(np.pi * x / h_len)

    def size(x: float) -> tuple[float, float]:
        s = x / h_len
        grip = 1.0 + p["grip_swell"] * np.exp(-((s - 0.3) / 0.18) ** 2)
        neck = 1.0 - p["neck_taper"] * np.clip((s - 0.7) / 0.25, 0.0, 1.0)
        end = 0.7 + 0.3 * np.sqrt(min(1.0, s / 0.04))
        return width / 2 * grip * neck * end, thick / 2 * (0.5 + 0.5 * grip * neck) * end

    handle = loft_along_x(np.concatenate([np.linspace(0.0, 0.04 * h_len, 4), np.linspace(0.06 * h_len, h_len, 24)]),
                          lambda x: superellipse(*size(x), 2.4, 24), centre, "toothbrush handle")
    head_len, head_w, plate_t = p["head_length"], p["head_width"], p["plate_thickness"]
    x0 = h_len - 0.006
    z_plate = centre(h_len)[1] - size(h_len)[1] + plate_t / 2

    def plate_size(x: float) -> tuple[float, float]:
        s = (x - x0) / head_len
        tip = np.sqrt(max(0.0, 1.0 - max(0.0, (s - 0.85) / 0.15) ** 2)) * 0.6 + 0.4 if s > 0.85 else 1.0
        return head_w / 2 * tip, plate_t / 2

    plate = loft_along_x(np.linspace(x0, x0 + head_len, 14), lambda x: superellipse(*plate_size(x), 3.0, 24),
                         lambda x: (0.0, z_plate), "toothbrush plate")
    tuft = superellipse(0.8 * head_len / 2 - 0.004 + 0.004, head_w / 2 - 0.0012, 5.0, 40)
    bristles = extrude(tuft, p["bristle_height"] + 0.001, "bristles").translate(
        (x0 + head_len * 0.52, 0.0, z_plate + plate_t / 2 - 0.001))
    return [("handle", handle), ("head", plate + bristles)], []


# ---------------------------------------------------------------------------------------------------- wine glass
def build_wine_glass(p: dict) -> Built:
    """Wine glass: revolved thin-walled bowl on a flared stem on a domed foot disc."""
    n = int(p["segments"])
    base_r, base_t = p["base_radius"], p["base_thickness"]
    base = revolve([(0.0, 0.0), (base_r, 0.0), (base_r, base_t * 0.5), (base_r - 0.004, base_t),
                    (0.012, base_t + 0.003), (0.0, base_t + 0.004)], n, "glass base")
    stem_r, stem_len = p["stem_radius"], p["stem_length"]
    z0, z1 = base_t, base_t + stem_len
    stem_profile = [(0.0, z0 - 0.001), (stem_r * 2.2, z0 - 0.001), (stem_r * 1.5, z0 + 0.004)]
    stem_profile += [(stem_r, z0 + 0.012), (stem_r, z1 - 0.008), (stem_r * 1.6, z1 + 0.001), (stem_r * 1.6, z1 + 0.004), (0.0, z1 + 0.004)]
    stem = revolve(stem_profile, n, "glass stem")
    radius, bowl_h, wall, widest = p["bowl_radius"], p["bowl_height"], p["wall"], p["widest"]
    rim_r = p["rim_radius"]
    bowl_bottom = z1 - 0.002
    s = np.linspace(0.0, 1.0, 22)[1:]
    outer = []
    for si in s:
        if si <= widest:
            r = radius * np.sqrt(max(0.0, 1.0 - (1.0 - si / widest) ** 2))
        else:
            r = radius - (radius - rim_r) * ((si - widest) / (1.0 - widest)) ** 1.5
        outer.append((max(r, stem_r * 1.7), bowl_bottom + bowl_h * si))
    inner = [(max(r - wall, 0.0005), z) for r, z in outer[::-1] if z > bowl_bottom + 0.008]
    profile = [(0.0, bowl_bottom), (stem_r * 1.7, bowl_bottom), *outer, (rim_r - wall, bowl_bottom + bowl_h), *inner[1:],
               (0.0, inner[-1][1] - 0.001)]
    bowl = revolve(profile, n, "glass bowl")
    return [("stem", stem), ("bowl", bowl), ("base", base)], [(0.0, 0.0, bowl_bottom + 0.7 * bowl_h)]


BUILDERS: dict[str, Callable[[dict], Built]] = {
    "mug": build_mug,
    "knife": build_knife,
    "hammer": build_hammer,
    "screwdriver": build_screwdriver,
    "spatula": build_spatula,
    "bottle": build_bottle,
    "frying_pan": build_frying_pan,
    "toothbrush": build_toothbrush,
    "wine_glass": build_wine_glass,
    "scissors": build_scissors,
    "kettle": build_kettle,
    "eyeglasses": build_glasses,
}

_MUG = dict(radius_bottom=0.04, radius_top=0.04, height=0.095, wall=0.005, floor=0.007, foot_chamfer=0.003,
            handle_style="D", handle_top=0.8, handle_bottom=0.25, handle_reach=0.028, handle_corner=0.3,
            handle_thickness=0.009, handle_width=0.013, handle_swell=0.1, segments=48)
_KNIFE = dict(blade_length=0.2, blade_height=0.046, spine_thickness=0.0024, tip_drop=0.25, edge_rise_start=0.45,
              spine_drop_start=0.6, spine_curve=2.0, edge_curve=2.0, handle_length=0.125, handle_width=0.024,
              handle_thickness=0.018, handle_offset=-0.004, handle_swell=0.08, handle_squareness=2.6)
_HAMMER = dict(handle_length=0.31, handle_width=0.032, handle_thickness=0.024, neck_taper=0.25, head_style="claw",
               head_depth=0.026, head_height=0.026, eye_length=0.036, face_radius=0.0145, face_neck=0.018,
               claw_bend=0.055, claw_angle=1.1, peen_neck=0.01, peen_radius=0.014, head_length=0.1)
_SCREWDRIVER = dict(handle_length=0.1, handle_radius=0.015, front_taper=0.3, lobes=6, lobe_depth=0.1,
                    shaft_radius=0.003, shaft_length=0.12, tip_length=0.012, tip="flat")
_SPATULA = dict(handle_length=0.16, handle_width=0.024, handle_thickness=0.015, handle_lift=0.03, blade_thickness=0.0025,
                blade_length=0.1, blade_width=0.07, blade_squareness=5.0, neck_length=0.05, neck_width=0.018,
                neck_thickness=0.004, slots=0)
_BOTTLE = dict(radius=0.033, height=0.2, neck_radius=0.0125, shoulder_start=0.62, neck_start=0.85, ring_height=0.93,
               cap_radius=0.0155, cap_height=0.02, cap_ridges=36, segments=48, support_ring=True)
_PAN = dict(radius_bottom=0.085, radius_top=0.11, height=0.045, wall=0.003, handle_height=0.7, handle_length=0.18,
            handle_width=0.026, handle_thickness=0.016, handle_angle=12.0, segments=64)
_TOOTHBRUSH = dict(handle_length=0.15, handle_width=0.013, handle_thickness=0.009, bow=0.0, grip_swell=0.2,
                   neck_taper=0.45, head_length=0.032, head_width=0.012, plate_thickness=0.005, bristle_height=0.011)
_GLASS = dict(base_radius=0.035, base_thickness=0.004, stem_radius=0.0038, stem_length=0.075, bowl_radius=0.043,
              bowl_height=0.1, widest=0.45, rim_radius=0.036, wall=0.002, segments=48)
_SCISSORS = dict(blade_length=0.095, blade_width=0.0105, tip_width=0.0025, blade_thickness=0.0022, edge_overlap=0.0015,
                 tang=0.014, taper=1.3, handle_thickness=0.008, loop_bar=0.0055, shank_length=0.028, shank_width=0.009,
                 loop_a_x=0.017, loop_a_y=0.01, loop_b_x=0.011, loop_b_y=0.009, loop_offset=0.017, pivot_radius=0.0035,
                 head_radius=0.0048, head_height=0.0012)
_KETTLE = dict(radius=0.08, base_radius=0.074, top_radius=0.045, height=0.12, belly=0.35, lid_dome=0.012,
               knob_radius=0.011, knob_height=0.016, spout_path=[[-0.03, 0.22], [0.0, 0.38], [0.035, 0.8]],
               spout_bend=0.02, spout_root=0.013, spout_tip=0.007, handle_style="arch", handle_thickness=0.016,
               handle_width=0.022, handle_attach=0.78, handle_clearance=0.035, handle_low=0.25, handle_reach=0.03)
_GLASSES = dict(lens_half_width=0.026, lens_half_height=0.02, rim_width=0.006, front_thickness=0.0045,
                lens_squareness=3.2, bridge_gap=0.018, top_bar=0.0045, bridge_height=0.05, bridge_arch=0.45,
                bridge_width=0.0035, hinge_height=0.55, temple_thickness=0.0035, temple_width=0.0055,
                temple_length=0.14, ear_fraction=0.25, ear_bend=25.0)


def _spec(object_id: str, category: str, base: dict, materials: tuple[str, ...], **changes: object) -> ObjectSpec:
    unknown = set(changes) - set(base)
    if unknown:
        raise ValueError(f"{object_id}: unknown parameters {sorted(unknown)}")
    return ObjectSpec(object_id, category, {**base, **changes}, materials)


#: The 36 objects, one category after another; the first of each category is its reference variant.
OBJECT_SPECS: tuple[ObjectSpec, ...] = (
    _spec("mug_classic", "mug", _MUG, ("ceramic", "ceramic")),
    _spec("mug_tapered", "mug", _MUG, ("ceramic", "ceramic"), radius_bottom=0.032, radius_top=0.041, height=0.1,
          handle_style="ring", handle_reach=0.004, handle_top=0.78, handle_bottom=0.3, foot_chamfer=0.004),
    _spec("mug_espresso", "mug", _MUG, ("ceramic", "ceramic"), radius_bottom=0.029, radius_top=0.03, height=0.062,
          wall=0.0045, floor=0.006, handle_style="ring", handle_reach=0.003, handle_top=0.76, handle_bottom=0.32,
          handle_thickness=0.007, handle_width=0.01),
    _spec("mug_tall", "mug", _MUG, ("ceramic", "ceramic"), radius_bottom=0.037, radius_top=0.036, height=0.12,
          handle_reach=0.03, handle_corner=0.22, handle_top=0.85, handle_bottom=0.2, handle_width=0.015,
          handle_thickness=0.01, foot_chamfer=0.006),
    _spec("knife_chef", "knife", _KNIFE, ("wood", "steel")),
    _spec("knife_paring", "knife", _KNIFE, ("plastic", "steel"), blade_length=0.09, blade_height=0.02,
          spine_thickness=0.0018, tip_drop=0.4, edge_rise_start=0.35, spine_drop_start=0.5, handle_length=0.1,
          handle_width=0.02, handle_thickness=0.016, handle_squareness=2.2),
    _spec("knife_bread", "knife", _KNIFE, ("wood", "steel"), blade_length=0.21, blade_height=0.028, tip_drop=0.5,
          edge_rise_start=0.86, spine_drop_start=0.86, handle_length=0.13, handle_swell=0.04, handle_squareness=3.2),
    _spec("hammer_claw", "hammer", _HAMMER, ("wood", "steel")),
    _spec("hammer_ballpeen", "hammer", _HAMMER, ("wood", "steel"), head_style="ballpeen", handle_length=0.3,
          face_radius=0.015, eye_length=0.03, face_neck=0.022, neck_taper=0.2),
    _spec("hammer_mallet", "hammer", _HAMMER, ("wood", "rubber"), head_style="mallet", handle_length=0.26,
          handle_width=0.03, handle_thickness=0.025, neck_taper=0.1, head_depth=0.06, face_radius=0.03,
          head_length=0.1),
    _spec("screwdriver_flat", "screwdriver", _SCREWDRIVER, ("plastic", "steel")),
    _spec("screwdriver_phillips", "screwdriver", _SCREWDRIVER, ("rubber_grip", "steel"), tip="cross",
          handle_length=0.105, handle_radius=0.0155, lobes=8, lobe_depth=0.08, shaft_radius=0.0028, shaft_length=0.15),
    _spec("screwdriver_stubby", "screwdriver", _SCREWDRIVER, ("plastic", "steel"), handle_length=0.06,
          handle_radius=0.017, front_taper=0.25, shaft_length=0.04, tip_length=0.008),
    _spec("spatula_turner", "spatula", _SPATULA, ("plastic", "nylon")),
    _spec("spatula_slotted", "spatula", _SPATULA, ("wood", "nylon"), slots=3, blade_width=0.075, blade_length=0.11,
          handle_length=0.17, handle_width=0.026, handle_thickness=0.017),
    _spec("spatula_scraper", "spatula", _SPATULA, ("plastic", "silicone"), blade_width=0.045, blade_length=0.085,
          blade_thickness=0.004, blade_squareness=2.8, handle_width=0.02, handle_thickness=0.013, neck_width=0.014,
          handle_lift=0.025),
    _spec("bottle_water", "bottle", _BOTTLE, ("hdpe_cap", "pet_bottle_bulk")),
    _spec("bottle_beer", "bottle", _BOTTLE, ("tin_cap", "glass_bottle_bulk"), radius=0.031, height=0.23,
          shoulder_start=0.55, neck_start=0.72, ring_height=0.95, cap_radius=0.0148, cap_height=0.007, cap_ridges=21,
          support_ring=False),
    _spec("bottle_sauce", "bottle", _BOTTLE, ("hdpe_cap", "pet_bottle_bulk"), radius=0.026, height=0.19,
          neck_radius=0.011, shoulder_start=0.7, neck_start=0.82, ring_height=0.9, cap_radius=0.0145,
          cap_height=0.025, cap_ridges=30),
    _spec("bottle_jar", "bottle", _BOTTLE, ("hdpe_cap", "jar_bulk"), radius=0.037, height=0.11, neck_radius=0.03,
          shoulder_start=0.75, neck_start=0.84, ring_height=0.86, cap_radius=0.0335, cap_height=0.018, cap_ridges=60),
    _spec("frying_pan_24", "frying_pan", _PAN, ("bakelite", "aluminium")),
    _spec("frying_pan_20", "frying_pan", _PAN, ("bakelite", "aluminium"), radius_bottom=0.07, radius_top=0.092,
          height=0.04, handle_length=0.16, handle_width=0.024, handle_thickness=0.015),
    _spec("frying_pan_crepe", "frying_pan", _PAN, ("wood", "aluminium"), radius_bottom=0.1, radius_top=0.112,
          height=0.02, handle_height=0.65, handle_length=0.2, handle_angle=8.0),
    _spec("toothbrush_classic", "toothbrush", _TOOTHBRUSH, ("plastic", "nylon")),
    _spec("toothbrush_ergonomic", "toothbrush", _TOOTHBRUSH, ("rubber_grip", "nylon"), bow=0.006, grip_swell=0.35,
          handle_length=0.155, handle_width=0.014, head_length=0.03),
    _spec("toothbrush_kids", "toothbrush", _TOOTHBRUSH, ("plastic", "nylon"), handle_length=0.11, handle_width=0.017,
          handle_thickness=0.012, grip_swell=0.3, head_length=0.024, head_width=0.011, bristle_height=0.009,
          neck_taper=0.4),
    _spec("wine_glass_red", "wine_glass", _GLASS, ("glass", "glass", "glass")),
    _spec("wine_glass_flute", "wine_glass", _GLASS, ("glass", "glass", "glass"), bowl_radius=0.028, bowl_height=0.13,
          widest=0.35, rim_radius=0.024, stem_length=0.08, base_radius=0.032),
    _spec("wine_glass_coupe", "wine_glass", _GLASS, ("glass", "glass", "glass"), bowl_radius=0.05, bowl_height=0.045,
          widest=0.9, rim_radius=0.049, stem_length=0.09, base_radius=0.038),
    _spec("scissors_office", "scissors", _SCISSORS, ("plastic", "steel", "steel")),
    _spec("scissors_kitchen", "scissors", _SCISSORS, ("plastic", "steel", "steel"), blade_length=0.105,
          blade_width=0.013, tip_width=0.003, blade_thickness=0.0026, loop_a_x=0.022, loop_a_y=0.012, loop_b_x=0.013,
          loop_b_y=0.011, loop_bar=0.0065, handle_thickness=0.0095, shank_length=0.03, loop_offset=0.02),
    _spec("scissors_kids", "scissors", _SCISSORS, ("plastic", "steel", "steel"), blade_length=0.05,
          blade_width=0.0085, tip_width=0.006, blade_thickness=0.0018, loop_a_x=0.011, loop_a_y=0.009,
          loop_b_x=0.011, loop_b_y=0.009, handle_thickness=0.0075, shank_length=0.018, loop_offset=0.0145,
          head_radius=0.0042, pivot_radius=0.003),
    _spec("kettle_stovetop", "kettle", _KETTLE, ("bakelite", "steel_tube_bulk", "kettle_bulk", "steel_lid_bulk")),
    _spec("kettle_gooseneck", "kettle", _KETTLE, ("wood", "steel_tube_bulk", "kettle_bulk", "steel_lid_bulk"),
          radius=0.058, base_radius=0.056, top_radius=0.037, height=0.12, belly=0.55, lid_dome=0.008,
          knob_radius=0.009, knob_height=0.014, spout_path=[[-0.015, 0.12], [0.02, 0.12], [0.055, 0.92], [0.1, 0.88]],
          spout_bend=0.035, spout_root=0.0065, spout_tip=0.0035, handle_style="side", handle_thickness=0.014,
          handle_width=0.02, handle_attach=0.82, handle_low=0.3, handle_reach=0.035),
    _spec("eyeglasses_acetate", "eyeglasses", _GLASSES, ("acetate", "acetate", "acetate")),
    _spec("eyeglasses_aviator", "eyeglasses", _GLASSES, ("steel", "steel", "steel"), lens_half_width=0.028,
          lens_half_height=0.024, rim_width=0.0024, front_thickness=0.0022, lens_squareness=2.3, bridge_gap=0.017,
          top_bar=0.0022, bridge_height=0.2, bridge_arch=0.3, bridge_width=0.0022, hinge_height=0.45,
          temple_thickness=0.002, temple_width=0.0028, ear_fraction=0.28, ear_bend=30.0),
)

CATEGORY_PARTS: dict[str, tuple[str, ...]] = {
    "mug": ("handle", "body"),
    "knife": ("handle", "blade"),
    "hammer": ("handle", "head"),
    "screwdriver": ("handle", "shaft"),
    "spatula": ("handle", "blade"),
    "bottle": ("cap", "body"),
    "frying_pan": ("handle", "pan"),
    "toothbrush": ("handle", "head"),
    "wine_glass": ("stem", "bowl", "base"),
    "scissors": ("handle", "blade", "pivot"),
    "kettle": ("handle", "spout", "body", "lid"),
    "eyeglasses": ("rim", "bridge", "temple"),
}


def spec_by_id(object_id: str) -> ObjectSpec:
    """The spec of one object; ValueError listing the known ids if absent."""
    for spec in OBJECT_SPECS:
        if spec.object_id == object_id:
            return spec
    raise ValueError(f"unknown object id {object_id!r}; known: {[s.object_id for s in OBJECT_SPECS]}")
