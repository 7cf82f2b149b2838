#!/usr/bin/env python3
"""Writes motions/garments/quad_skirt.obj: a test mesh garment as an artist exports one.

A flared tube of quads around the CMU skeleton's hips in its bind pose (metres, y up, the hips
joint at the origin: docs/guide/mesh_garments.md), with what the procedural skirt lacks: UVs with
a seam (the ring's last column of faces uses u = 1 where its first uses u = 0, so those vertices
carry two UVs), per-vertex normals, one pentagon and one triangle in place of a quad (n-gons and
mixed faces), and two OBJ groups without materials (`waist`, the top row of faces, and `skirt`).
Run from the repository root: python3 scripts/make_quad_skirt.py
"""
import math

COLUMNS, ROWS = 24, 10           # vertices around, rings down
WAIST, HEM = 0.19, 0.27          # ring radii, m
TOP, BOTTOM = 0.06, -0.42        # ring heights, m


def main():
    out = ["# clothdb test garment: written by scripts/make_quad_skirt.py (do not edit)"]
    out.append("o quad_skirt")
    for r in range(ROWS):
        s = r / (ROWS - 1)
        radius, y = WAIST + s * (HEM - WAIST), TOP + s * (BOTTOM - TOP)
        for c in range(COLUMNS):
            phi = 2 * math.pi * c / COLUMNS
            out.append("v %.6f %.6f %.6f" % (radius * math.sin(phi), y, radius * math.cos(phi)))
    # An extra vertex in the middle of one bottom edge makes that face a pentagon.
    phi_mid = 2 * math.pi * 10.5 / COLUMNS
    out.append("v %.6f %.6f %.6f" % (HEM * math.sin(phi_mid), BOTTOM, HEM * math.cos(phi_mid)))
    extra = ROWS * COLUMNS + 1  # 1-based
    for r in range(ROWS):
        for c in range(COLUMNS + 1):  # one column more: the UV seam
            out.append("vt %.6f %.6f" % (c / COLUMNS, 1 - r / (ROWS - 1)))
    out.append("vt %.6f %.6f" % (10.5 / COLUMNS, 0.0))
    extra_uv = ROWS * (COLUMNS + 1) + 1
    slope = math.atan2(HEM - WAIST, TOP - BOTTOM)
    for c in range(COLUMNS):
        phi = 2 * math.pi * c / COLUMNS
        out.append("vn %.6f %.6f %.6f" % (math.cos(slope) * math.sin(phi), math.sin(slope),
                                          math.cos(slope) * math.cos(phi)))
    out.append("vn %.6f %.6f %.6f" % (math.cos(slope) * math.sin(phi_mid), math.sin(slope),
                                      math.cos(slope) * math.cos(phi_mid)))
    extra_n = COLUMNS + 1

    def corner(r, c):
        v = r * COLUMNS + c % COLUMNS + 1
        t = r * (COLUMNS + 1) + c + 1
        n = c % COLUMNS + 1
        return "%d/%d/%d" % (v, t, n)

    for r in range(ROWS - 1):
        out.append("g " + ("waist" if r == 0 else "skirt"))
        for c in range(COLUMNS):
            # Outward-facing winding: down the column, across, up.
            a, b, d, e = corner(r, c), corner(r + 1, c), corner(r + 1, c + 1), corner(r, c + 1)
            if r == ROWS - 2 and c == 10:
                out.append("f %s %s %d/%d/%d %s %s" % (a, b, extra, extra_uv, extra_n, d, e))
            elif r == 4 and c == 3:
                out.append("f %s %s %s" % (a, b, d))
                out.append("f %s %s %s" % (a, d, e))
            else:
                out.append("f %s %s %s %s" % (a, b, d, e))
    with open("motions/garments/quad_skirt.obj", "w") as f:
        f.write("\n".join(out) + "\n")


if __name__ == "__main__":
    main()
