"""Twin categories with three or more parts and thin parts: scissors, kettles and folded eyeglasses.

Builders follow `assets.catalog`'s contract: a parameter dict (metres) in, parts in prompt order plus keep-open
probe points out, built in the resting pose on a table (z up). Every part is one connected region of the joined
surface: where a part has two pieces (two handle loops, two blades, two temples), the pieces overlap the way the
real object's do (closed scissors' halves are stacked, folded temples lie on each other).
"""

from __future__ import annotations

import manifold3d as mf
import numpy as np

from assets.shapes import Built, cylinder, extrude, revolve, rounded_polyline, superellipse, sweep


def _ring(inner_x: float, inner_y: float, bar: float, height: float, z0: float) -> mf.Manifold:
    """Oval finger loop lying flat: inner opening 2 inner_x by 2 inner_y, bar width `bar`, from z0 to z0 + height."""
    r_mid = inner_y + bar / 2
    section = superellipse(bar / 2, height / 2, 3.0, 24) + np.array([r_mid, height / 2])
    ring = revolve(section, 48, "finger loop")
    return ring.scale(((inner_x + bar / 2) / r_mid, 1.0, 1.0)).translate((0.0, 0.0, z0))


# ------------------------------------------------------------------------------------------------------ scissors
def build_scissors(p: dict) -> Built:
    """Closed scissors lying flat: two stacked steel blades (+x), their plastic loops (-x), a pivot screw on top.

    Half A lies on the table (blade and loop from z = 0), half B on top of it (raised by one blade thickness);
    the two blades overlap in a band along the cutting edges, the two shanks next to the pivot.
    """
    length, w0, w_tip, tb = p["blade_length"], p["blade_width"], p["tip_width"], p["blade_thickness"]
    overlap, tang = p["edge_overlap"], p["tang"]
    sink = 0.3 * tb  # half B sinks this far into half A so the stack is one solid
    xs = np.linspace(0.0, length, 16)
    width = w0 + (w_tip - w0) * (xs / length) ** p["taper"]
    tip = [(length + w_tip * 0.4 * np.cos(a), -overlap + w_tip / 2 + w_tip / 2 * np.sin(a))
           for a in np.linspace(-np.pi / 2, np.pi / 2, 7)]
    outline = np.array([(-tang, -overlap), *[(x, -overlap) for x in xs[1:-1]], *tip,
                        *[(x, w - overlap) for x, w in zip(xs[::-1][1:-1], width[::-1][1:-1])], (-tang, w0 - overlap)])
    boss = superellipse(p["head_radius"] + 0.0012, p["head_radius"] + 0.0012, 2.0, 40)  # round blade base at the pivot
    blade_a = extrude(outline, tb, "scissors blade") + extrude(boss, tb, "blade boss")
    blade_b = (extrude(outline * np.array([1.0, -1.0]), tb, "scissors blade") + extrude(boss, tb, "blade boss")).translate(
        (0.0, 0.0, tb - sink))

    h, bar = p["handle_thickness"], p["loop_bar"]
    z_b = tb - sink
    start = -(p["head_radius"] + 0.0015)
    handle = None
    z_a = 0.0003  # the loops stand on the table; the shank above the blade's flat underside (no coplanar faces)
    for side, z0, (ix, iy) in ((1.0, z_a, (p["loop_a_x"], p["loop_a_y"])), (-1.0, z_b, (p["loop_b_x"], p["loop_b_y"]))):
        centre = np.array([start - p["shank_length"] - ix - bar / 2, side * p["loop_offset"]])
        zc = z0 + h / 2
        path = rounded_polyline([(start, side * 0.0035, zc), (start - 0.4 * p["shank_length"], side * 0.005, zc),
                                 (centre[0] + ix + bar / 2, centre[1], zc)], [0.02], step=0.003)
        shank = sweep(path, lambda t: superellipse(h / 2, p["shank_width"] / 2 * (1.0 - 0.15 * t), 3.0, 20),
                      normal_hint=(0.0, 0.0, 1.0), what="scissors shank")
        loop = _ring(ix, iy, bar, h, z0).translate((float(centre[0]), float(centre[1]), 0.0))
        handle = shank + loop if handle is None else handle + shank + loop

    r_pin, r_head, head_h = p["pivot_radius"], p["head_radius"], p["head_height"]
    z_top = 2 * tb - sink
    pivot = cylinder(r_pin, z_top - 0.0003, "z", (0.0, 0.0, (z_top + 0.0003) / 2), 32)
    pivot = pivot + cylinder(r_head, head_h + 0.0003, "z", (0.0, 0.0, z_top + (head_h - 0.0003) / 2), 40,
                             radius_end=r_head * 0.8)
    loops = [(start - p["shank_length"] - p["loop_a_x"] - bar / 2, p["loop_offset"], z_a + h / 2),
             (start - p["shank_length"] - p["loop_b_x"] - bar / 2, -p["loop_offset"], z_b + h / 2)]
    return [("handle", handle), ("blade", blade_a + blade_b), ("pivot", pivot)], loops


# -------------------------------------------------------------------------------------------------------- kettle
def _kettle_radius(p: dict, z: float) -> float:
    """Outer radius of the kettle body at height z: swelling from the base to the belly, closing to the opening."""
    base, belly, top, height = p["base_radius"], p["radius"], p["top_radius"], p["height"]
    z_belly = p["belly"] * height
    if z <= z_belly:
        return base + (belly - base) * np.sin(0.5 * np.pi * z / z_belly)
    return top + (belly - top) * np.cos(0.5 * np.pi * (z - z_belly) / (height - z_belly))


def build_kettle(p: dict) -> Built:
    """Kettle on its base: revolved body, domed lid with a knob, a spout at +x and an arched top or a side handle."""
    height, top = p["height"], p["top_radius"]
    zs = np.linspace(0.004, height, 24)
    profile = [(0.0, 0.0), (p["base_radius"] - 0.004, 0.0), *[(_kettle_radius(p, z), z) for z in zs], (0.0, height)]
    body = revolve(profile, 64, "kettle body")

    # the lid covers the opening and sits on the body's flat top (no overhang: its collision hulls stay on it)
    lid_r, dome, knob_r, knob_h = top - 0.001, p["lid_dome"], p["knob_radius"], p["knob_height"]
    rs = np.linspace(lid_r, knob_r * 0.6, 8)
    dome_pts = [(r, height + 0.002 + dome * (1.0 - (r / lid_r) ** 2)) for r in rs]
    z_knob = dome_pts[-1][1]
    knob = [(knob_r * 0.6, z_knob + 0.4 * knob_h), (knob_r, z_knob + 0.55 * knob_h), (knob_r, z_knob + 0.85 * knob_h),
            (knob_r * 0.8, z_knob + knob_h), (0.0, z_knob + knob_h)]
    lid = revolve([(0.0, height - 0.001), (lid_r, height - 0.001), *dome_pts, *knob], 48, "kettle lid")

    # spout_path: (x beyond the belly radius, height as a fraction of the body's) per corner, in the xz plane
    spout_path = np.array([(p["radius"] + dx, 0.0, fz * height) for dx, fz in p["spout_path"]])
    r0, r1 = p["spout_root"], p["spout_tip"]
    spout = sweep(rounded_polyline(spout_path, [p["spout_bend"]] * (len(spout_path) - 2), step=0.004),
                  lambda t: superellipse(r0 + (r1 - r0) * t, r0 + (r1 - r0) * t, 2.0, 24), what="kettle spout")

    thick, width = p["handle_thickness"], p["handle_width"]
    z_att = p["handle_attach"] * height
    r_att = _kettle_radius(p, z_att)
    if p["handle_style"] == "arch":  # over the lid, across the spout's direction (y)
        z_top = z_knob + knob_h + p["handle_clearance"] + thick / 2
        half = top + 0.012
        pts = [(0, -(r_att - 0.005), z_att), (0, -(r_att + 0.01), z_att + 0.012), (0, -half, z_top), (0, half, z_top),
               (0, r_att + 0.01, z_att + 0.012), (0, r_att - 0.005, z_att)]
        path = rounded_polyline(pts, [0.01, 0.025, 0.025, 0.01], step=0.004)
        keep = (0.0, 0.0, 0.5 * (z_knob + knob_h + z_top - thick / 2))
        normal = (1.0, 0.0, 0.0)
    else:  # side handle at -x, D-shaped like a mug's
        z_low = p["handle_low"] * height
        x_out = max(r_att, _kettle_radius(p, z_low)) + p["handle_reach"]
        path = rounded_polyline([(-(r_att - 0.005), 0, z_att), (-x_out, 0, z_att), (-x_out, 0, z_low),
                                 (-(_kettle_radius(p, z_low) - 0.005), 0, z_low)], [0.025, 0.025], step=0.004)
        keep = (-0.5 * (x_out + _kettle_radius(p, 0.5 * (z_att + z_low))), 0.0, 0.5 * (z_att + z_low))
        normal = (0.0, 1.0, 0.0)
    handle = sweep(path, lambda t: superellipse(width / 2, thick / 2, 2.6, 24), normal_hint=normal, what="kettle handle")
    return [("handle", handle), ("spout", spout), ("body", body), ("lid", lid)], [keep]


# ------------------------------------------------------------------------------------------------------- glasses
def build_glasses(p: dict) -> Built:
    """Folded eyeglasses lying on their front: two lens rims joined by a top bar ("rim"), a nose bridge below the
    bar, and the two temples folded across the front, one on top of the other (no lenses)."""
    a, b, bar, t = p["lens_half_width"], p["lens_half_height"], p["rim_width"], p["front_thickness"]
    expo = p["lens_squareness"]
    xc = p["bridge_gap"] / 2 + bar / 2 + a
    outer = superellipse(a + bar / 2, b + bar / 2, expo, 72)
    inner = superellipse(a - bar / 2, b - bar / 2, expo, 72)
    holes = None
    rim = None
    for sign in (-1.0, 1.0):
        ring = extrude(outer, t, "rim") - extrude(inner, t + 0.002, "lens opening").translate((0.0, 0.0, -0.001))
        hole = extrude(inner, t + 0.004, "lens opening").translate((sign * xc, 0.0, -0.002))
        rim = ring.translate((sign * xc, 0.0, 0.0)) if rim is None else rim + ring.translate((sign * xc, 0.0, 0.0))
        holes = hole if holes is None else holes + hole
    def y_edge(half_x: float, half_y: float, x: float) -> float:  # the lens outline's y at x from the lens centre
        return half_y * (1.0 - (x / half_x) ** expo) ** (1.0 / expo)

    y_bar = 0.5 * (y_edge(a + bar / 2, b + bar / 2, 0.5 * a) + y_edge(a - bar / 2, b - bar / 2, 0.5 * a))
    top_bar = extrude(superellipse(xc - 0.4 * a, p["top_bar"] / 2, 6.0, 48), t, "top bar")
    rim = rim + (top_bar.translate((0.0, y_bar, 0.0)) - holes)

    x_inner = p["bridge_gap"] / 2 + bar / 2
    y0, arch = p["bridge_height"] * b, p["bridge_arch"] * b
    bridge_path = np.array([(-x_inner - 0.0005, y0, t / 2), (-0.5 * x_inner, y0 + 0.8 * arch, t / 2), (0.0, y0 + arch, t / 2),
                            (0.5 * x_inner, y0 + 0.8 * arch, t / 2), (x_inner + 0.0005, y0, t / 2)])
    bridge = sweep(rounded_polyline(bridge_path, [0.004, 0.004, 0.004], step=0.0015),
                   lambda s: superellipse(0.45 * t, p["bridge_width"] / 2, 3.0, 20), normal_hint=(0.0, 0.0, 1.0),
                   what="bridge")

    y_hinge = p["hinge_height"] * b
    x_end = xc + y_edge(b + bar / 2, a + bar / 2, y_hinge)  # the rim's outer edge at the hinge height
    tt, tw, length = p["temple_thickness"], p["temple_width"], p["temple_length"]
    angle = np.radians(p["ear_bend"])
    temples = None
    for level, sign in enumerate((-1.0, 1.0)):  # the left temple is folded first, the right one lies on it
        z = t + 0.0006 + tt / 2 + level * (tt - 0.0004)
        end_piece = extrude(superellipse(0.004, 0.0035, 4.0, 24), z + tt / 4, "end piece")
        rim = rim + (end_piece.translate((sign * (x_end + 0.001), y_hinge, 0.0)) - holes)
        straight = length * (1.0 - p["ear_fraction"])
        knee = (sign * (x_end - straight), y_hinge, z)
        tip = (knee[0] - sign * length * p["ear_fraction"] * np.cos(angle),
               y_hinge - length * p["ear_fraction"] * np.sin(angle), z)
        path = rounded_polyline([(sign * (x_end + 0.002), y_hinge, z), knee, tip], [0.03], step=0.004)
        temple = sweep(path, lambda s: superellipse(tt / 2, tw / 2 * (1.0 - 0.3 * s), 3.0, 20),
                       normal_hint=(0.0, 0.0, 1.0), what="temple")
        temples = temple if temples is None else temples + temple
    return [("rim", rim), ("bridge", bridge), ("temple", temples)], [(-xc, 0.0, t / 2), (xc, 0.0, t / 2)]
