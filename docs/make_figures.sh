#!/usr/bin/env bash
# Regenerates every committed figure under docs/figures/ (and the data they are drawn from) with the project's own
# commands, the same ones docs/reproduction.md, docs/usage.md and docs/accuracy.md quote.
#
#   docs/make_figures.sh                 # fig1 sweeps helical accuracy: everything (the accuracy study is most of it)
#   docs/make_figures.sh fig1 sweeps     # only these parts
#   docs/make_figures.sh redraw          # redraw every figure from the committed CSVs, computing nothing
#   docs/make_figures.sh speed           # also: docs/speed.txt (flagbot bench speed; not a figure)
#
# Parts, with their time on the 2-core VM at load ~1.4 and a warm kernel cache (docs/speed.md):
#   fig1      docs/figures/fig1_paper.png, fig1_design1.png, fig1_design2.png           (flagbot render; ~15 s)
#   sweeps    docs/figures/design1, design2, design1_length, design2_length: CSV + figures (flagbot sweep; ~30 s)
#   helical   docs/figures/helical_granular, helical_viscous: helical vs straight flagella (flagbot sweep; ~45 s)
#   accuracy  docs/accuracy.csv, docs/figures/accuracy_vs_time.png, accuracy_calibration.png
#             (flagbot bench accuracy, the whole study: ~12 min on an earlier 2-core VM, docs/accuracy.md; more
#             under load. ACCURACY_ARGS=--quick: 63 s on the 2-core VM at load ~1.7)
#   redraw    the sweeps' figures from their results.csv (flagbot sweep-plot) and the accuracy figures from
#             docs/accuracy.csv (flagbot bench accuracy --plot-from); seconds
#   speed     docs/speed.txt, headed by the host, its load and the date (flagbot bench speed; ~2.5 min)
#
# Each part computes into a temporary directory and replaces the committed files only when its command succeeded
# (the accuracy study's directory, $ACCURACY_OUT or a new /tmp/flagbot_accuracy.*, is kept: its tables are the
# ones docs/accuracy.md quotes). FLAGBOT overrides the command (default .venv/bin/flagbot), e.g.
# FLAGBOT="python -m flagbot_sim"; ACCURACY_ARGS=--quick checks the accuracy part in about a minute (a smaller
# study: do not commit what it writes).
set -euo pipefail
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST   # nothing here uses DDS; if anything ever does, it stays on this machine
export MPLBACKEND=Agg
cd "$(dirname "$0")/.."
read -r -a FLAGBOT <<< "${FLAGBOT:-.venv/bin/flagbot}"
FIG=docs/figures
TMP=$(mktemp -d)
trap 'rm -rf "$TMP"' EXIT

step() {  # step LABEL COMMAND...: run it, say how long it took
    local label=$1 start=$SECONDS
    shift
    echo "== $label: $*" >&2
    "$@"
    echo "== $label: done in $((SECONDS - start)) s" >&2
}

fig1() {
    step "Fig. 1, the paper's layout" "${FLAGBOT[@]}" render design1 design2 --layout paper --out "$TMP/fig1_paper.png"
    step "Fig. 1, design 1" "${FLAGBOT[@]}" render design1 --out "$TMP/fig1_design1.png"
    step "Fig. 1, design 2" "${FLAGBOT[@]}" render design2 --out "$TMP/fig1_design2.png"
    mv "$TMP"/fig1_paper.png "$TMP"/fig1_design1.png "$TMP"/fig1_design2.png "$FIG/"
}

sweep() {  # sweep NAME SCENE GRID...: the full grid of one of the paper's figures into docs/figures/NAME
    local name=$1 scene=$2
    shift 2
    step "sweep $name" "${FLAGBOT[@]}" sweep "$scene" "$@" --out "$TMP/$name" --quiet
    rm -rf "${FIG:?}/$name"
    mv "$TMP/$name" "$FIG/$name"
}

sweeps() {
    sweep design1 design1 --grid n=2,3 --grid rpm=20:250:10
    sweep design2 design2 --grid n=2,3 --grid rpm=20:250:10
    sweep design1_length design1 --grid L=0.09,0.111,0.13 --grid n=2,3 --grid rpm=20:250:10
    sweep design2_length design2 --grid L=0.07,0.089,0.11 --grid n=2,3 --grid rpm=20:250:10
}

helical() {
    # docs/helical_viscous.md: helical vs straight flagella of design 1 in the paper's granular medium and in a
    # glycerin-like fluid (DER only: the beam balance is of straight flagella). The beam-deflection and length
    # figures of a DER-only, one-length sweep are empty or repeat the speed figure: removed
    sweep helical_granular design1 --grid n=2,3 --grid rpm=20:250:10 --grid flagellum.helix_pitch=0,-0.05,-0.12 \
        --frameworks der
    sweep helical_viscous design1 --set medium.model=viscous --set medium.mu=1.2 --grid n=2,3 \
        --grid rpm=20:250:10 --grid flagellum.helix_pitch=0,-0.05,-0.12 --frameworks der
    rm -f "$FIG"/helical_*/deflection_*.png "$FIG"/helical_*/speed_vs_length_*.png
    step "Fig. 1 with helical flagella" "${FLAGBOT[@]}" render design1 --set flagellum.helix_pitch=-0.05 \
        --out "$TMP/fig1_helical.png"
    mv "$TMP/fig1_helical.png" "$FIG/"
}

accuracy() {
    # the study's own tables (accuracy.md, accuracy.json) stay in $ACCURACY_OUT: docs/accuracy.md quotes them
    local out=${ACCURACY_OUT:-$(mktemp -d /tmp/flagbot_accuracy.XXXXXX)}
    step "accuracy study" "${FLAGBOT[@]}" bench accuracy ${ACCURACY_ARGS:-} --out "$out"
    cp "$out/accuracy.csv" docs/accuracy.csv
    cp "$out/accuracy_vs_time.png" "$out/accuracy_calibration.png" "$FIG/"
    echo "   the study's tables are in $out/accuracy.md: compare docs/accuracy.md's with them" >&2
}

redraw() {
    local dir
    for dir in design1 design2 design1_length design2_length helical_granular helical_viscous; do
        step "redraw $dir" "${FLAGBOT[@]}" sweep-plot "$FIG/$dir"
    done
    rm -f "$FIG"/helical_*/deflection_*.png "$FIG"/helical_*/speed_vs_length_*.png
    step "redraw accuracy" "${FLAGBOT[@]}" bench accuracy --plot-from docs/accuracy.csv --out "$FIG"
}

speed() {
    local load
    load=$(cut -d' ' -f1-3 /proc/loadavg)
    step "speed" "${FLAGBOT[@]}" bench speed > "$TMP/speed.txt"
    {
        echo "# flagbot bench speed: $(nproc) cores ($(uname -m)), load average $load at the start and" \
             "$(cut -d' ' -f1-3 /proc/loadavg) at the end; $(date -u '+%Y-%m-%d %H:%M UTC'). See docs/speed.md."
        cat "$TMP/speed.txt"
    } > docs/speed.txt
}

parts=("$@")
[ ${#parts[@]} -gt 0 ] || parts=(fig1 sweeps helical accuracy)
for part in "${parts[@]}"; do
    case "$part" in
        fig1|sweeps|helical|accuracy|redraw|speed) "$part" ;;
        *) echo "error: unknown part '$part' (fig1, sweeps, helical, accuracy, redraw, speed)" >&2; exit 2 ;;
    esac
done
echo "done: git status docs/ shows what changed" >&2
