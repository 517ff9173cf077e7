#!/usr/bin/env bash
# Set up (idempotently) and run the project.
#
#   ./run.sh main [ARGS...]   the main job: the paper's permutation experiment on a small default
#                             (10 trials, 4 chains, into runs/paper-small; ARGS override, e.g.
#                             --trials 100 --chains paper -o runs/paper)
#   ./run.sh test [ARGS...]   the test suite (pytest; ARGS go to pytest, e.g. -m slow)
#
# Both create or refresh the virtual environment .venv (override with SQKIT_VENV) from
# pyproject.toml at the versions pinned in constraints.txt (those the README's numbers were measured
# with, for Python 3.11; SQKIT_CONSTRAINTS= or another Python: the newest within pyproject's ranges),
# and install the system library libosmesa6 through apt-get when it is missing.
set -euo pipefail
cd "$(dirname "$0")"

VENV="${SQKIT_VENV:-.venv}"
CONSTRAINTS="${SQKIT_CONSTRAINTS-constraints.txt}"

log() { printf '[run.sh] %s\n' "$*" >&2; }

ensure_osmesa() {
    if dpkg -s libosmesa6 >/dev/null 2>&1; then return; fi
    log "installing libosmesa6 (off-screen OpenGL for the default renderer) with apt-get"
    local sudo=""
    if [ "$(id -u)" -ne 0 ]; then
        if command -v sudo >/dev/null 2>&1; then sudo="sudo"; else
            log "error: libosmesa6 is missing and this user cannot run apt-get; install it as root:"
            log "       apt-get install -y libosmesa6"
            exit 1
        fi
    fi
    $sudo apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq libosmesa6 >/dev/null
}

pick_python() {
    for py in python3.11 python3.12 python3.13 python3.10 python3; do
        if command -v "$py" >/dev/null 2>&1 &&
            "$py" -c 'import sys; sys.exit(sys.version_info < (3, 10))' 2>/dev/null; then
            echo "$py"; return
        fi
    done
    log "error: Python >= 3.10 is required"; exit 1
}

ensure_venv() {
    local stamp="$VENV/.sqkit-installed" want pins="" have pinned_for
    if [ ! -x "$VENV/bin/python" ]; then
        log "creating virtual environment $VENV"
        "$(pick_python)" -m venv "$VENV"
    fi
    if [ -n "$CONSTRAINTS" ]; then
        if [ ! -f "$CONSTRAINTS" ]; then log "error: constraints file $CONSTRAINTS not found"; exit 1; fi
        have="$("$VENV/bin/python" -c 'import sys; print("%d.%d" % sys.version_info[:2])')"
        pinned_for="$(sed -n 's/^# for-python: *//p' "$CONSTRAINTS")"
        if [ -n "$pinned_for" ] && [ "$have" != "$pinned_for" ]; then
            log "note: $CONSTRAINTS pins the versions for Python $pinned_for; $VENV has Python $have:" \
                "installing the newest within pyproject.toml's ranges instead"
        else
            pins="$CONSTRAINTS"
        fi
    fi
    want="$(cat pyproject.toml ${pins:+"$pins"} | sha256sum | cut -d' ' -f1)"
    if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
        log "installing Python dependencies into $VENV (first run takes a few minutes)"
        "$VENV/bin/python" -m pip install -q --upgrade pip
        "$VENV/bin/python" -m pip install -q ${pins:+-c "$pins"} -e ".[test,cluster,bench,slam,formats,viz]"
        echo "$want" > "$stamp"
    fi
}

cmd="${1:-}"
[ $# -gt 0 ] && shift
case "$cmd" in
    main)
        ensure_osmesa; ensure_venv
        exec "$VENV/bin/sqsim" experiment scenes/paper.toml -o runs/paper-small --trials 10 \
            --chains 1-2-3D,1-2-3D-3A,1-2-3D-3F,default --workers 2 "$@"
        ;;
    test)
        ensure_osmesa; ensure_venv
        exec "$VENV/bin/python" -m pytest "$@"
        ;;
    *)
        awk 'NR > 1 && !/^#/ { exit } NR > 1 { sub(/^# ?/, ""); print }' "$0"
        [ -z "$cmd" ] || [ "$cmd" = "-h" ] || [ "$cmd" = "--help" ] || exit 2
        ;;
esac
