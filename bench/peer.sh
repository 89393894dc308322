#!/usr/bin/env bash
# bench/peer.sh — our methods against BRIEF's peer, Embark texture-synthesis (CLI 0.8.3),
# side by side (docs/benchmarks.md, "Peer"). Not part of CI: it builds the peer and runs
# every synthesis once, a few minutes in all on 2 cores.
#
# Usage: bench/peer.sh [-m METHOD]... [-o DIR] [EXAMPLE[@X,Y,SIZE]]...
#   -m METHOD   a `surfsynth synth --method` (repeatable; default: all four, the default first)
#   -o DIR      work directory (default: target/peer-bench); the table is DIR/peer.md
#   EXAMPLE     an image; @X,Y,SIZE takes its SIZE² crop at (X, Y) first
#               (default: bricks, scales and gravel from ../shared/data/textures, below)
#
# For each example: the peer with default settings (`--out-size 512 generate E`), and
# `surfsynth synth --mesh grid.obj --example E --resolution 32 --orient +x --method M` on
# the flat 16x16-quad grid (512² texels) for each method; pf1/pf4/pf8 of both by
# `surfsynth eval` (the peer's PNG with `eval --image`, ours from the result directory:
# the same pixel-grid windows), wall seconds of each process by /usr/bin/time.
set -euo pipefail

ROOT="$(cd "$(dirname "$0")/.." && pwd)"
SHARED="${SURFSYNTH_SHARED:-$ROOT/../shared}"
TEX="$SHARED/data/textures"
OUT="$ROOT/target/peer-bench"
methods=()
examples=()
while [ $# -gt 0 ]; do
    case "$1" in
        -m) methods+=("$2"); shift 2 ;;
        -o) OUT="$2"; shift 2 ;;
        -h|--help) sed -n '2,17p' "$0"; exit 0 ;;
        -*) echo "error: unknown option $1 (see $0 --help)" >&2; exit 2 ;;
        *) examples+=("$1"); shift ;;
    esac
done
[ ${#methods[@]} -gt 0 ] || methods=(optimise patches coherent multiscale)
if [ ${#examples[@]} -eq 0 ]; then
    # Default list (all ≤ 256² so that the 512² output is a real extension):
    # bricks (mortar lines), reptile scales (whole scales ~30 px), gravel (stochastic).
    examples=(
        "$TEX/skimage_brick.png@128,128,256"
        "$TEX/krita_reptile_scales.png@128,128,256"
        "$TEX/etr_gravel.png"
    )
fi

TIME=/usr/bin/time
[ -x "$TIME" ] || { echo "error: $TIME not found (GNU time)" >&2; exit 1; }
PEER_ROOT="$ROOT/target/peer"
PEER="$PEER_ROOT/bin/texture-synthesis"
if [ ! -x "$PEER" ]; then
    echo "building the peer into $PEER_ROOT (once) ..." >&2
    cargo install texture-synthesis-cli --version 0.8.3 --locked --root "$PEER_ROOT" >&2
fi
(cd "$ROOT" && cargo build --release --quiet)
SURF="$ROOT/target/release/surfsynth"

mkdir -p "$OUT"
"$SURF" bench grid --size 16 --out "$OUT/grid.obj"

# A top-level number of `eval`'s pretty JSON (null or missing: empty).
get() { sed -n "s/^  \"$2\": \([-0-9.eE+]*\),\{0,1\}$/\1/p" "$1" | head -n 1; }
# The pf_detail method of `eval`'s JSON.
how() { sed -n 's/^    "method": "\([a-z]*\)",\{0,1\}$/\1/p' "$1" | head -n 1; }
ratio() { awk -v a="$1" -v b="$2" 'BEGIN { if (a == "" || b == "" || b + 0 == 0) print "–"; else printf "%.2f", a / b }'; }
fmt() { awk -v a="$1" 'BEGIN { if (a == "") print "–"; else printf "%.3f", a }'; }
fmt2() { awk -v a="$1" 'BEGIN { if (a == "") print "–"; else printf "%.2f", a }'; }
secs() { awk '{ print $1 }' "$1"; }
cpu() { awk '{ print $2 }' "$1"; }

table="$OUT/peer.md"
{
    echo "Peer comparison ($(date -u +%Y-%m-%d), $(nproc) cores, commit $(git -C "$ROOT" rev-parse --short HEAD 2>/dev/null || echo '?'))."
    echo "Ratios are ours / peer: below 1 is better for pfS and seconds. Load average at start: $(cut -d' ' -f1-3 /proc/loadavg 2>/dev/null || echo '?')."
    echo
    echo "| example | method | eval | pf1 ours | pf1 peer | pf4 ours | pf4 peer | **pf4 ratio** | pf8 ours | pf8 peer | **pf8 ratio** | s ours | s peer | **s ratio** | CPU-s ratio |"
    echo "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"
} > "$table"

for spec in "${examples[@]}"; do
    path="${spec%@*}"
    name="$(basename "$path")"
    name="${name%.*}"
    work="$OUT/$name"
    mkdir -p "$work"
    if [ "$spec" != "$path" ]; then
        IFS=, read -r x y size <<< "${spec#*@}"
        name="$name ${size}² at $x,$y"
        "$SURF" bench crop "$path" --at "$x,$y" --size "$size" --out "$work/example.png"
    else
        cp "$path" "$work/example.png"
    fi
    ex="$work/example.png"

    echo "$name: peer ..." >&2
    if "$TIME" -f "%e %U %M" -o "$work/peer.time" \
        "$PEER" --out-size 512 --out "$work/peer.png" generate "$ex" > "$work/peer.log" 2>&1 \
        && "$SURF" eval --image "$work/peer.png" --example "$ex" > "$work/peer.json"; then
        p1=$(get "$work/peer.json" pf1); p4=$(get "$work/peer.json" pf4); p8=$(get "$work/peer.json" pf8)
        ps=$(secs "$work/peer.time"); pc=$(cpu "$work/peer.time")
    else
        echo "  peer failed (see $work/peer.log)" >&2
        p1=; p4=; p8=; ps=; pc=
    fi

    for m in "${methods[@]}"; do
        echo "$name: surfsynth --method $m ..." >&2
        res="$work/$m"
        if "$TIME" -f "%e %U %M" -o "$work/$m.time" \
            "$SURF" synth --mesh "$OUT/grid.obj" --example "$ex" --resolution 32 --orient +x \
                --method "$m" --out "$res" > "$work/$m.log" 2>&1 \
            && "$SURF" eval "$res" --example "$ex" > "$work/$m.json"; then
            o1=$(get "$work/$m.json" pf1); o4=$(get "$work/$m.json" pf4); o8=$(get "$work/$m.json" pf8)
            os=$(secs "$work/$m.time"); oc=$(cpu "$work/$m.time"); how_=$(how "$work/$m.json")
        else
            echo "  $m failed (see $work/$m.log)" >&2
            o1=; o4=; o8=; os=; oc=; how_="failed"
        fi
        echo "| $name | $m | $how_ | $(fmt "$o1") | $(fmt "$p1") | $(fmt "$o4") | $(fmt "$p4") | **$(ratio "$o4" "$p4")** | $(fmt "$o8") | $(fmt "$p8") | **$(ratio "$o8" "$p8")** | $(fmt2 "$os") | $(fmt2 "$ps") | **$(ratio "$os" "$ps")** | $(ratio "$oc" "$pc") |" >> "$table"
    done
done

cat "$table"
echo >&2
echo "table: $table (outputs and logs under $OUT)" >&2
