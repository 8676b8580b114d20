# bench/lib.sh - what the benchmarks that start real daemons share. Source it
# after setting VBM, VBW, CTL (bench_ctl), OUT and PORT; it kills every
# process it started when the script exits.
#
#   next_ports                 WEP, CEP: the next two free loopback ports from PORT
#   start_master LOG ARGS...   a master on WEP/CEP (MPID), once it answers
#   start_workers N            N workers of 1 thread (WPIDS), once all joined
#   stop_all PID...            TERM, then wait for each

PIDS=()
cleanup() { for p in "${PIDS[@]}"; do kill -9 "$p" 2>/dev/null || true; done; }
trap cleanup EXIT

port_free() { ! (exec 3<>"/dev/tcp/127.0.0.1/$1") 2>/dev/null; }
next_ports() {
    while ! port_free "$PORT" || ! port_free $((PORT + 1)); do PORT=$((PORT + 2)); done
    WEP="tcp://127.0.0.1:$PORT"
    CEP="tcp://127.0.0.1:$((PORT + 1))"
    PORT=$((PORT + 2))
}
start_master() {
    local log=$1
    shift
    "$VBM" --workers "$WEP" --control "$CEP" "$@" 2>>"$log" &
    MPID=$!
    PIDS+=("$MPID")
    for _ in $(seq 100); do "$CTL" "$CEP" workers >/dev/null 2>&1 && return 0; sleep 0.05; done
    echo "$(basename "$0"): the master does not answer" >&2
    return 1
}
start_workers() {
    WPIDS=()
    for i in $(seq "$1"); do
        "$VBW" --master "$WEP" --threads 1 --name "w$i" 2>>"$OUT/workers.log" &
        WPIDS+=($!)
        PIDS+=($!)
    done
    "$CTL" "$CEP" wait-workers "$1" 20 >/dev/null
}
stop_all() {
    for p in "$@"; do kill -TERM "$p" 2>/dev/null || true; done
    for p in "$@"; do wait "$p" 2>/dev/null || true; done
}
