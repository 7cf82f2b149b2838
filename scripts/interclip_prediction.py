#!/usr/bin/env python3
"""Measures whether a clip predicted from an earlier clip along the same primary clip would code
more cheaply than the clip itself (docs/notebook/BENCHMARKS.md, "Codec v2 in the precompute": the
explorer's clips along one edge start from nearby states and follow the same body motion). Exports
every cloth clip of DB with `clothdb clip export`, writes OUT/B.pc2 (every clip as stored, in id
order) and OUT/D.pc2 (the same, but each clip after the first along its primary clip replaced by its
difference from that first clip), then compare
    clothdb bench codec --input OUT/B.pc2 --bounds 0.1,1 --codecs v1 --comparison-only
    clothdb bench codec --input OUT/D.pc2 --bounds 0.1,1 --codecs v1 --comparison-only
A decoder would add the reference clip back, so D's ratio is what inter-clip prediction could
reach on top of codec v1's own predictors. Pure Python (no numpy); a few minutes on the demo.

Usage: scripts/interclip_prediction.py DB OUT [CLOTHDB]
"""
import array
import os
import sqlite3
import struct
import subprocess
import sys


def read_pc2(path):
    data = open(path, "rb").read()
    _, _, points, _, _, samples = struct.unpack("<12siiffi", data[:32])
    frames = array.array("f")
    frames.frombytes(data[32:])
    return points, samples, frames


def write_pc2(path, points, frames):
    with open(path, "wb") as f:
        f.write(struct.pack("<12siiffi", b"POINTCACHE2\0", 1, points, 0.0, 1.0,
                            len(frames) // (3 * points)))
        frames.tofile(f)


def main():
    if len(sys.argv) not in (3, 4):
        sys.exit(__doc__)
    db, out = sys.argv[1], sys.argv[2]
    clothdb = sys.argv[3] if len(sys.argv) == 4 else "build/cli/clothdb"
    os.makedirs(out, exist_ok=True)
    rows = sqlite3.connect(db).execute(
        "SELECT id, primary_clip FROM cloth_clip ORDER BY id").fetchall()
    every, predicted = array.array("f"), array.array("f")
    reference = {}
    points = 0
    for clip, primary in rows:
        folder = os.path.join(out, str(clip))
        if not os.path.exists(os.path.join(folder, "cloth.pc2")):
            subprocess.run([clothdb, "clip", "export", db, str(clip), "--out", folder], check=True,
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        points, _, frames = read_pc2(os.path.join(folder, "cloth.pc2"))
        every.extend(frames)
        first = reference.get(primary)
        if first is None or len(first) != len(frames):
            reference.setdefault(primary, frames)
            predicted.extend(frames)
        else:
            predicted.extend(array.array("f", (a - b for a, b in zip(frames, first))))
    write_pc2(os.path.join(out, "B.pc2"), points, every)
    write_pc2(os.path.join(out, "D.pc2"), points, predicted)
    print(f"{len(rows)} clips, {len(every) // (3 * points)} frames of {points} vertices, "
          f"{len(reference)} primary clips: wrote {out}/B.pc2 and {out}/D.pc2")


if __name__ == "__main__":
    main()
