#!/usr/bin/env bash
# The example outputs in docs/GUIDE.md, made by running the guide's commands (so that they
# cannot go stale). On a small database made here in a few seconds (tests/data/mpi_small.json:
# a 192-vertex skirt on CMU 01_01, 10 nodes, 14 edges), each example's commands run in a
# temporary folder that holds links to motions/, scripts/ and tests/data/, so the commands read as
# a reader types them from the repository root. Times, dates, durations and the temporary folder
# are masked, so the same binary gives the same text.
#
#   scripts/guide_examples.sh                    write the outputs into docs/GUIDE.md
#   scripts/guide_examples.sh --check            exit 1 naming every example whose output differs
#   options: --clothdb PATH (default build/cli/clothdb), --guide FILE (default docs/GUIDE.md)
#
# In the guide an example is the text between `<!-- example: NAME -->` and `<!-- /example -->`;
# this script owns it (edit the commands here, never the output there).
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
CLOTHDB=$ROOT/build/cli/clothdb
GUIDE=$ROOT/docs/GUIDE.md
CHECK=0
while [ $# -gt 0 ]; do
  case $1 in
    --check) CHECK=1 ;;
    --clothdb) CLOTHDB=${2:?--clothdb needs a path}; shift ;;
    --guide) GUIDE=${2:?--guide needs a file}; shift ;;
    -h | --help) sed -n '2,16p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//'; exit 0 ;;
    *) echo "guide_examples.sh: unknown argument '$1' (see --help)" >&2; exit 2 ;;
  esac
  shift
done
[ -x "$CLOTHDB" ] || { echo "guide_examples.sh: $CLOTHDB: no clothdb executable (build it, or give --clothdb)" >&2; exit 2; }
[ -f "$GUIDE" ] || { echo "guide_examples.sh: $GUIDE: no such file" >&2; exit 2; }
CLOTHDB=$(cd "$(dirname "$CLOTHDB")" && pwd)/$(basename "$CLOTHDB")

WORK=$(mktemp -d "${TMPDIR:-/tmp}/clothdb_guide.XXXXXX")
trap 'rm -rf "$WORK"' EXIT
mkdir -p "$WORK/run/tests" "$WORK/out"
ln -s "$ROOT/motions" "$WORK/run/motions"
ln -s "$ROOT/tests/data" "$WORK/run/tests/data"
ln -s "$ROOT/scripts" "$WORK/run/scripts"
export LC_ALL=C TZ=UTC
clothdb() { "$CLOTHDB" "$@"; }

# What differs between two runs of the same binary, and nothing else: wall and CPU times, the
# run's timestamps, CPU times and the forecast made from them, the user who ran it, and the
# temporary folder.
mask() {
  sed -E \
    -e "s#$WORK/run/##g; s#$WORK/run#.#g; s#$ROOT/##g" \
    -e 's#[0-9]{4}-[0-9]{2}-[0-9]{2}[T ][0-9]{2}:[0-9]{2}:[0-9]{2}(\.[0-9]+)?Z?#<time>#g' \
    -e 's#built in [0-9.]+ s#built in <t> s#g' \
    -e 's#[0-9.]+ s this run \([0-9.]+ CPU-s per stored frame\)#<t> s this run (<t> CPU-s per stored frame)#g' \
    -e 's#in [0-9.]+ CPU s#in <t> CPU s#g' \
    -e 's#^(runs +[0-9]+), [0-9.]+ CPU s#\1, <t> CPU s#' \
    -e 's#[0-9.e+-]+ CPU-h to converge#<t> CPU-h to converge#g' \
    -e 's#made at [0-9.e+-]+ CPU-h#made at <t> CPU-h#g' \
    -e 's#^budget( +)[0-9.]+ CPU s counted#budget\1<t> CPU s counted#' \
    -e 's#largest batch [0-9.]+ CPU s#largest batch <t> CPU s#g' \
    -e 's#linear decline of dead ends \+ unexplored ways out fitted on the last half of the run, [0-9]+ fewer per CPU-h#linear decline of dead ends + unexplored ways out fitted on the last half of the run, <n> fewer per CPU-h#g' \
    -e 's#uid [0-9]+#uid <n>#g'
}

# example NAME EXIT_CODE COMMAND... : runs each command line (as written in the guide) in the
# work folder, stdout and stderr together, and expects the last one to exit with EXIT_CODE.
example() {
  local name=$1 want=$2 rc=0 cmd
  shift 2
  : >"$WORK/out/$name"
  for cmd in "$@"; do
    printf '$ %s\n' "$cmd" >>"$WORK/out/$name"
    rc=0
    (cd "$WORK/run" && eval "$cmd") >"$WORK/out/$name.raw" 2>&1 || rc=$?
    mask <"$WORK/out/$name.raw" >>"$WORK/out/$name"
  done
  rm -f "$WORK/out/$name.raw"
  if [ "$rc" != "$want" ]; then
    echo "guide_examples.sh: example '$name': '$cmd' exited with $rc, expected $want:" >&2
    cat "$WORK/out/$name" >&2
    exit 1
  fi
  echo "$name" >>"$WORK/names"
}

example graph-build 0 'clothdb graph build motions/cmu_walk.json --clips 01_01 --db small.db'
example precompute-refused 1 'clothdb precompute tests/data/mpi_small.json --db small.db --epsilon 10 --threads 1 --quiet'
example precompute 0 'clothdb precompute tests/data/mpi_small.json --db small.db --epsilon 66 --threads 1 --quiet'
example db-check 0 'clothdb db check small.db'
example db-info 0 'clothdb db info small.db'
example clips-list 0 'clothdb clips list small.db --worst 4 --by strain'
example clip-show 0 'clothdb clip show small.db 9 --png clip9.png'
example clip-resim 0 'clothdb db dump small.db --tables cloth_state,cloth_clip,cloth_edge,cloth_link,cloth_clip_steering > before.dump' \
  'clothdb clip resim small.db 9 --substeps 24 --max-frames 300 --quiet' \
  'clothdb clips list small.db --worst 2 --by strain'
example clip-import 0 'clothdb clip export small.db 9 --out clip9' \
  'python3 scripts/pc2_offset.py clip9/cloth.pc2 --from-frame 5 --mm 0,0,100  # stands in for Blender' \
  'clothdb clip import small.db 9 clip9' \
  'clothdb clip import small.db 9 clip9 --on-break ramp'
example undo 0 'clothdb clip log small.db' \
  'clothdb undo small.db' \
  'clothdb undo small.db' \
  'clothdb db dump small.db --tables cloth_state,cloth_clip,cloth_edge,cloth_link,cloth_clip_steering | cmp - before.dump && echo "every cloth row as before the edits"'

# Put each output between its markers (or compare in --check mode).
python3 - "$GUIDE" "$WORK/out" "$WORK/names" "$CHECK" <<'EOF'
import pathlib, re, sys
guide, out_dir, names_file, check = pathlib.Path(sys.argv[1]), pathlib.Path(sys.argv[2]), sys.argv[3], sys.argv[4] == "1"
names = pathlib.Path(names_file).read_text().split()
text = guide.read_text(encoding="utf-8")
block = re.compile(r"(<!-- example: ([a-z0-9-]+) -->\n)(.*?)(<!-- /example -->)", re.S)
found = [m.group(2) for m in block.finditer(text)]
problems = []
for name in sorted(set(found) - set(names)):
    problems.append(f"{guide}: example '{name}' is not made by scripts/guide_examples.sh")
for name in names:
    if found.count(name) != 1:
        problems.append(f"{guide}: example '{name}' must appear exactly once between "
                        f"'<!-- example: {name} -->' and '<!-- /example -->' (found {found.count(name)})")
if problems:
    print("\n".join(problems), file=sys.stderr)
    sys.exit(1)
differ = []
def fill(m):
    name = m.group(2)
    new = "```text\n" + (out_dir / name).read_text(encoding="utf-8") + "```\n"
    if m.group(3) != new:
        differ.append(name)
    return m.group(1) + new + m.group(4)
updated = block.sub(fill, text)
if check:
    if differ:
        print(f"{guide}: the output of example(s) {', '.join(differ)} differs from what the commands print now: "
              "run scripts/guide_examples.sh and commit the guide", file=sys.stderr)
        sys.exit(1)
    print(f"{guide}: {len(names)} examples current")
else:
    guide.write_text(updated, encoding="utf-8")
    print(f"{guide}: {len(names)} examples written ({len(differ)} changed)")
EOF
