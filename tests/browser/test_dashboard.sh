#!/usr/bin/env bash
# test_dashboard.sh - the dashboard in a real browser: headless Chromium
# (Debian's `chromium`) against a real vbrender-master, a vbrender-worker
# and `vbrender serve` on loopback. Run by `make test-browser` (and so by
# `make check`).
#
#   - the jobs page lists the running job;
#   - the job page's image is replaced as the job runs (the page counts its
#     refreshes in data-refreshes; SKIPPED on a master without previews);
#   - the workers page lists the worker;
#   - cancel works: the page's form posted as a browser posts it, then the
#     jobs page shows the job cancelled;
#   - with the master killed the page says "master unreachable", and it
#     recovers by itself when a master answers again;
#   - a screenshot of the job page is kept: build/test-artifacts/dashboard.png
#     (and jobs.png).
#
# The browser runs with --virtual-time-budget, so the pages' timers (1 s
# refreshes) run for that much page time before the DOM is dumped.
#
# The job must still run through the checks whatever the host's speed: the
# worker is frozen (SIGSTOP) once the job has samples, and the master's
# heartbeats are 30 s apart, so it keeps the frozen worker listed (a silent
# worker is dropped after 5 heartbeats) and the job running to the end.
# Exit status 0 when every check passed (or was skipped, with a SKIPPED:
# line saying why), 1 otherwise.
set -u
cd "$(dirname "$0")/../.."
BIN=${VB_BINDIR:-bin}
ART=${VB_ARTIFACTS:-build/test-artifacts}
TMP=$(mktemp -d "${TMPDIR:-/tmp}/vb-browser.XXXXXX")
mkdir -p "$ART"
pids=()
fails=0
checks=0

cleanup() {
    for p in "${pids[@]}"; do kill -9 "$p" 2>/dev/null; wait "$p" 2>/dev/null; done
    if [ "$fails" = 0 ]; then rm -rf "$TMP"; else echo "logs kept in $TMP"; fi
}
trap cleanup EXIT

ok() { checks=$((checks + 1)); echo "ok: $*"; }
fail() {
    fails=$((fails + 1))
    echo "FAIL: $*"
    for f in "$TMP"/*.log; do echo "--- $f"; tail -n 15 "$f"; done
}

BROWSER=$(command -v chromium || command -v chromium-browser || true)
if [ -z "$BROWSER" ]; then
    echo "SKIPPED: browser test: no chromium (make deps installs it)"
    exit 0
fi

# --no-sandbox: the sandbox needs user namespaces, which containers and
# root (CI) do not give; nothing but our own pages is loaded.
# A start can take long on a loaded machine: a run that fails is tried once more.
browse() { # browse OUTFILE ARGS... : the DOM (or a screenshot) after 5 s of page time
    local out=$1
    shift
    local t0 rc profile
    for attempt in 1 2; do
        t0=$SECONDS
        # a profile per run: one still held by an earlier run's lingering
        # processes makes the next run wait on it
        profile=$(mktemp -d "$TMP/profile.XXXXXX")
        timeout 90 "$BROWSER" --headless=new --no-sandbox --disable-gpu --no-first-run \
            --user-data-dir="$profile" --virtual-time-budget=5000 "$@" >"$out" \
            2>>"$TMP/chromium.log"
        rc=$?
        [ $rc = 0 ] && return 0
        echo "chromium exited with status $rc after $((SECONDS - t0)) s (try $attempt): $*"
    done
    return $rc
}

# An HTTP request through bash's /dev/tcp: METHOD PATH [HEADER...]; the
# whole reply (status line, headers, body) on stdout.
http() {
    local method=$1 path=$2
    shift 2
    exec 3<>"/dev/tcp/127.0.0.1/$HTTP_PORT" || return 1
    {
        printf '%s %s HTTP/1.0\r\nHost: 127.0.0.1:%s\r\n' "$method" "$path" "$HTTP_PORT"
        for h in "$@"; do printf '%s\r\n' "$h"; done
        printf '\r\n'
    } >&3
    cat <&3
    exec 3<&-
}

start_master() {
    "$BIN/vbrender-master" --workers "tcp://127.0.0.1:$PORT" --control "$CEP" \
        --heartbeat-ms 30000 --state none >"$TMP/master.log" 2>&1 &
    MASTER=$!
    pids+=("$MASTER")
    for _ in $(seq 100); do
        grep -q listening "$TMP/master.log" && return 0
        grep -q "cannot bind" "$TMP/master.log" && return 1
        sleep 0.1
    done
    return 1
}

# ports below Linux's ephemeral range, by pid so that runs side by side differ
for try in 0 1 2 3; do
    PORT=$((26000 + ($$ % 500) * 8 + 2 * try))
    CEP="tcp://127.0.0.1:$((PORT + 1))"
    start_master && break
    MASTER=
done
[ -n "${MASTER:-}" ] || { fail "the master does not start"; exit 1; }
"$BIN/vbrender-worker" --master "tcp://127.0.0.1:$PORT" --threads 2 --name browser-w1 \
    >"$TMP/worker.log" 2>&1 &
WORKER=$!
pids+=("$WORKER")

# SIGSTOP, then wait until every thread of the worker has stopped.
freeze() {
    kill -STOP "$WORKER" || return 1
    for _ in $(seq 1000); do
        sed -n 's/.*) \(.\) .*/\1/p' /proc/"$WORKER"/task/*/stat 2>/dev/null | grep -qv '[TtZX]' ||
            return 0
        sleep 0.01
    done
    return 1
}
# The job's merged samples, as its status (JSON) says.
samples() {
    "$BIN/vbrender" status "$JOB" --master "$CEP" 2>/dev/null |
        sed -n 's/.*"samples":[[:space:]]*\([0-9.e+]*\).*/\1/p' | head -n 1
}
"$BIN/vbrender" serve --master "$CEP" --listen 127.0.0.1:0 >"$TMP/serve.log" 2>&1 &
pids+=($!)
for _ in $(seq 100); do
    HTTP_PORT=$(sed -n 's|.*http://127.0.0.1:\([0-9]*\)/.*|\1|p' "$TMP/serve.log")
    [ -n "$HTTP_PORT" ] && break
    sleep 0.1
done
[ -n "$HTTP_PORT" ] || { fail "vbrender serve does not start"; exit 1; }
URL="http://127.0.0.1:$HTTP_PORT"

# the worker joins, then is frozen; the job (1024 layers) is submitted and
# the worker thawed for short slices until the job has samples
for _ in $(seq 150); do
    "$BIN/vbrender" workers --master "$CEP" 2>/dev/null | grep -q "^127.0.0.1 " && break
    sleep 0.1
done
freeze || { fail "the worker does not stop"; exit 1; }
JOB=$("$BIN/vbrender" submit scenes/cornell-box.json --master "$CEP" --spp 4096 --granularity 4 \
    2>>"$TMP/client.log" | tail -n 1)
[ "$JOB" = 1 ] || { fail "submit: job '$JOB'"; exit 1; }
for _ in $(seq 3000); do
    kill -CONT "$WORKER"
    sleep 0.005
    freeze
    s=$(samples)
    [ -n "$s" ] && [ "$s" != 0 ] && break
done

# 1. the jobs page lists the running job
browse "$TMP/jobs.html" --dump-dom "$URL/"
if grep -q "<tr id=\"job-$JOB\" data-state=\"running\">" "$TMP/jobs.html" &&
    grep -q "cornell-box.json" "$TMP/jobs.html"; then
    ok "the jobs page lists job $JOB, running"
else
    fail "the jobs page does not list job $JOB as running: $(grep -o '<tbody>.*</tbody>' "$TMP/jobs.html")"
fi
browse /dev/null --screenshot="$ART/jobs.png" --window-size=1280,800 "$URL/"

# 2. the job page's image is replaced while the job runs
browse "$TMP/job.html" --dump-dom "$URL/job/$JOB"
n=$(sed -n 's/.*<img id="preview"[^>]*data-refreshes="\([0-9]*\)".*/\1/p' "$TMP/job.html")
if grep -q "no previews" "$TMP/job.html"; then
    echo "SKIPPED: browser test: the job page's image: the master has no preview command yet"
elif [ "${n:-0}" -ge 2 ] && grep -q '<img id="preview"[^>]*src="blob:' "$TMP/job.html"; then
    ok "the job page's image was refreshed $n times in 5 s"
else
    fail "the job page's image was refreshed ${n:-0} times: $(grep -o '<img id="preview"[^>]*>' "$TMP/job.html")"
fi
if grep -q 'id="state" class="state-running">running<' "$TMP/job.html"; then
    ok "the job page shows the job running"
else
    fail "the job page does not show the job running"
fi
rm -f "$ART/dashboard.png"
browse /dev/null --screenshot="$ART/dashboard.png" --window-size=1280,800 "$URL/job/$JOB"
[ -s "$ART/dashboard.png" ] && ok "screenshot: $ART/dashboard.png" || fail "no screenshot"

# the workers page lists the worker with its threads
browse "$TMP/workers.html" --dump-dom "$URL/workers"
if grep -q '<tr><td class="l">127.0.0.1</td><td>2</td>' "$TMP/workers.html"; then
    ok "the workers page lists the worker with 2 threads"
else
    fail "the workers page: $(grep -o '<tbody>.*</tbody>' "$TMP/workers.html" | head -c 400)"
fi

# 3. cancel: the job page's form, posted as a browser does, goes back to the
# job's page; then the pages show the job cancelled
action=$(sed -n 's/.*<form id="cancel" method="post" action="\([^"]*\)".*/\1/p' "$TMP/job.html")
reply=$(http POST "$action" "Origin: $URL" "Accept: text/html" \
    "Content-Type: application/x-www-form-urlencoded" "Content-Length: 0")
if [[ "$reply" == "HTTP/1.1 303"* ]] && grep -qi "^Location: /job/$JOB" <<<"$reply"; then
    ok "the cancel form ($action) answers 303 to /job/$JOB"
else
    fail "the cancel form ($action): $(head -n 1 <<<"$reply")"
fi
browse "$TMP/jobs2.html" --dump-dom "$URL/"
if grep -q "<tr id=\"job-$JOB\" data-state=\"cancelled\">" "$TMP/jobs2.html"; then
    ok "the jobs page shows job $JOB cancelled"
else
    fail "the jobs page does not show job $JOB cancelled"
fi
browse "$TMP/job2.html" --dump-dom "$URL/job/$JOB"
if grep -q '<button type="submit" disabled="">' "$TMP/job2.html"; then
    ok "the job page's cancel button is disabled once the job ended"
else
    fail "the job page's cancel button is still enabled"
fi

# 4. the master away, then back
{ kill -9 "$MASTER" && wait "$MASTER"; } 2>/dev/null
browse "$TMP/away.html" --dump-dom "$URL/"
if grep -q '<div id="banner" class="shown">master unreachable: ' "$TMP/away.html"; then
    ok "with the master away the page says: master unreachable"
else
    fail "no 'master unreachable' banner: $(grep -o '<div id="banner"[^<]*' "$TMP/away.html")"
fi
start_master || fail "the master does not start again"
# The server answers 503 at once for a second after a request got no answer
# (so a page does not wait out the timeout on every call), and the
# browser's virtual time can spend its whole budget inside that second:
# wait, in real time, until the API answers again, as a person's page
# would by retrying, then look at the page.
for _ in $(seq 50); do
    [[ "$(http GET /api/jobs | head -n 1)" == "HTTP/1.1 200"* ]] && break
    sleep 0.2
done
browse "$TMP/back.html" --dump-dom "$URL/"
if grep -q '<div id="banner" class="">' "$TMP/back.html" &&
    ! grep -q '<body data-refreshes="0"' "$TMP/back.html"; then
    ok "the page recovers when the master is back"
else
    fail "the page did not recover: $(grep -o '<div id="banner"[^<]*' "$TMP/back.html")"
fi

echo "browser test: $checks passed, $fails failed"
[ "$fails" = 0 ]
