#!/usr/bin/env python3
"""Strain that a per-coordinate codec bound adds to a garment's edges.

Reads an OBJ (e.g. `clothdb clip export DB ID --out DIR` writes DIR/cloth.obj), adds independent
uniform errors in [-b, b] to every coordinate (what a quantiser with step 2b does to a frame), and
prints the 99th percentile and the largest relative change of edge length over N noisy frames for
each bound b. Usage: scripts/quantisation_strain.py DIR/cloth.obj [frames] [bounds in mm ...]
"""
import math
import random
import sys


def main():
    if len(sys.argv) < 2 or sys.argv[1] in ("-h", "--help"):
        print(__doc__.strip())
        return 0 if len(sys.argv) >= 2 else 2
    path = sys.argv[1]
    frames = int(sys.argv[2]) if len(sys.argv) > 2 else 20
    bounds = [float(b) for b in sys.argv[3:]] or [0.5, 0.25, 0.1, 0.05]
    verts, edges = [], set()
    try:
        with open(path) as f:
            for line in f:
                p = line.split()
                if not p:
                    continue
                if p[0] == "v":
                    verts.append(tuple(map(float, p[1:4])))
                elif p[0] == "f":
                    idx = [int(x.split("/")[0]) - 1 for x in p[1:]]
                    for i in range(len(idx)):
                        a, b = idx[i], idx[(i + 1) % len(idx)]
                        edges.add((min(a, b), max(a, b)))
    except OSError as e:
        print(f"{path}: {e.strerror}", file=sys.stderr)
        return 1
    if not verts or not edges:
        print(f"{path}: no vertices or faces", file=sys.stderr)
        return 1
    edges = sorted(edges)
    lengths = sorted(math.dist(verts[a], verts[b]) for a, b in edges)
    print(f"{path}: {len(verts)} vertices, {len(edges)} edges, length min {1e3 * lengths[0]:.1f} "
          f"median {1e3 * lengths[len(lengths) // 2]:.1f} max {1e3 * lengths[-1]:.1f} mm")
    rng = random.Random(1)
    for bound_mm in bounds:
        b = bound_mm * 1e-3
        strains = []
        for _ in range(frames):
            noisy = [tuple(c + rng.uniform(-b, b) for c in v) for v in verts]
            strains += [math.dist(noisy[i], noisy[j]) / math.dist(verts[i], verts[j]) - 1
                        for i, j in edges]
        strains.sort()
        print(f"bound {bound_mm:.2f} mm: edge strain added p99 {100 * strains[int(0.99 * (len(strains) - 1))]:.2f} % "
              f"max {100 * strains[-1]:.2f} % ({frames} frames)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
