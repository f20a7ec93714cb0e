# Sourced by .ci scripts: start_sim OUTFILE DEVICE... starts `pymb simulate`
# (the checkout's .venv) on a new pseudo-terminal, waits until it prints the
# path (bounded: 20 s), and sets SIM_PID and SIM_PORT; stop_sim stops it by PID.
start_sim() {
    local out=$1 i
    shift
    "${PYMB_PY:-.venv/bin/python}" -m pymb simulate "$@" > "$out" 2>&1 &
    SIM_PID=$!
    for i in $(seq 200); do
        SIM_PORT=$(head -n 1 "$out" 2>/dev/null || true)
        case $SIM_PORT in /dev/*) return 0 ;; esac
        kill -0 "$SIM_PID" 2>/dev/null || break
        sleep 0.1
    done
    echo "the simulator did not start: $(cat "$out")" >&2
    return 1
}

stop_sim() {
    [ -z "${SIM_PID:-}" ] || { kill "$SIM_PID" 2>/dev/null || true; wait "$SIM_PID" 2>/dev/null || true; }
    SIM_PID=
}

# A CSV from hub_read with every number replaced by N: what the markers
# decoded to (offline, no sensor ...) and the table's shape, which must be the
# same on every architecture (the values themselves move between reads).
hub_shape() {
    sed 's/-\{0,1\}[0-9][0-9.]*/N/g' "$1"
}
