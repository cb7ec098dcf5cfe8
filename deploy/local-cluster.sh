#!/usr/bin/env bash
# A lessmap site on one machine, to try several instances: 2 Zenoh routers (a mesh) and
# 3 service instances, all on loopback.
#
#   deploy/local-cluster.sh start [--dir DIR] [--ports PORT_A,PORT_B] [--instances N]
#   deploy/local-cluster.sh status [--dir DIR]
#   deploy/local-cluster.sh stop [--dir DIR]
#
# start: routers on tcp/127.0.0.1:PORT_A and :PORT_B (free ports unless --ports), router B
# connected to router A and A to B; instances local-1..local-N (default 3) as clients of
# both routers (each prefers one, and moves to the other if it goes away), each with its
# own state directory DIR/state/local-I. Logs in DIR/*.log, PIDs in DIR/*.pid, the
# endpoints in DIR/endpoints. DIR defaults to ./lessmap-cluster.
# stop: SIGTERM to every process this script started (by the PIDs in DIR, instances
# first), then waits for them; a process that outlives its wait gets SIGKILL.
#
# Runs `lessmap` from PATH; set LESSMAP="python -m lessmap" (or a path) to use another.
# Extra `lessmap serve` options for every instance: LESSMAP_SERVE_ARGS="--memory-only".
set -euo pipefail

LESSMAP=${LESSMAP:-lessmap}
DIR=./lessmap-cluster
PORTS=""
INSTANCES=3

usage() {
    sed -n '2,19p' "$0" | sed 's/^# \{0,1\}//'
    exit "${1:-0}"
}

command=${1:-}
[ -n "$command" ] || usage 2
shift
while [ $# -gt 0 ]; do
    case $1 in
        --dir) DIR=$2; shift 2 ;;
        --ports) PORTS=$2; shift 2 ;;
        --instances) INSTANCES=$2; shift 2 ;;
        -h|--help) usage 0 ;;
        *) echo "local-cluster.sh: unknown option $1" >&2; usage 2 ;;
    esac
done

free_port() {
    python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'
}

# Is PID alive and one of ours (a lessmap process), not a reused PID?
ours() {
    local pid=$1
    kill -0 "$pid" 2>/dev/null || return 1
    tr '\0' ' ' <"/proc/$pid/cmdline" 2>/dev/null | grep -q lessmap
}

# Start one process in the background; record its PID in DIR/NAME.pid.
launch() {
    local name=$1
    shift
    # shellcheck disable=SC2086  # LESSMAP may be a command with arguments
    nohup $LESSMAP "$@" >"$DIR/$name.log" 2>&1 &
    echo $! >"$DIR/$name.pid"
}

# Wait until a router logs that it listens (or dies).
wait_listening() {
    local name=$1 pid
    pid=$(cat "$DIR/$name.pid")
    for _ in $(seq 1 100); do
        grep -q "router listening on" "$DIR/$name.log" 2>/dev/null && return 0
        if ! kill -0 "$pid" 2>/dev/null; then
            echo "local-cluster.sh: $name did not start:" >&2
            cat "$DIR/$name.log" >&2
            return 1
        fi
        sleep 0.1
    done
    echo "local-cluster.sh: $name is not listening after 10 s (see $DIR/$name.log)" >&2
    return 1
}

start() {
    mkdir -p "$DIR"
    for pidfile in "$DIR"/*.pid; do
        if [ -e "$pidfile" ] && ours "$(cat "$pidfile")"; then
            echo "local-cluster.sh: $DIR already runs a cluster; '$0 stop --dir $DIR' first" >&2
            exit 1
        fi
    done
    rm -f "$DIR"/*.pid
    local port_a port_b
    if [ -n "$PORTS" ]; then
        port_a=${PORTS%%,*}
        port_b=${PORTS#*,}
    else
        port_a=$(free_port)
        port_b=$(free_port)
    fi
    local a="tcp/127.0.0.1:$port_a" b="tcp/127.0.0.1:$port_b"
    launch router-a router -l "$a" -e "$b"
    launch router-b router -l "$b" -e "$a"
    wait_listening router-a || { stop; exit 1; }
    wait_listening router-b || { stop; exit 1; }
    printf 'router-a %s\nrouter-b %s\n' "$a" "$b" >"$DIR/endpoints"
    local i first second
    for i in $(seq 1 "$INSTANCES"); do
        # Spread the instances over the routers: odd ones prefer A, even ones B.
        if [ $((i % 2)) -eq 1 ]; then first=$a second=$b; else first=$b second=$a; fi
        mkdir -p "$DIR/state/local-$i"
        # shellcheck disable=SC2086  # word splitting of the extra options is intended
        # One process per instance (--workers 1): the script shows instances sharing a fleet.
        launch "local-$i" serve -m client -e "$first" -e "$second" --workers 1 \
            --instance "local-$i" --state-dir "$DIR/state/local-$i" ${LESSMAP_SERVE_ARGS:-}
    done
    echo "routers: $a (router-a), $b (router-b)"
    echo "instances: $(seq -s ' ' -f 'local-%g' 1 "$INSTANCES") (logs and PIDs in $DIR)"
    echo "robots and apps: connect to either router, e.g. lessmap watch -e $a"
    echo "stop: $0 stop --dir $DIR"
}

status() {
    local pidfile name pid
    [ -f "$DIR/endpoints" ] && cat "$DIR/endpoints"
    for pidfile in "$DIR"/*.pid; do
        [ -e "$pidfile" ] || continue
        name=$(basename "$pidfile" .pid)
        pid=$(cat "$pidfile")
        if ours "$pid"; then echo "$name pid $pid running"; else echo "$name pid $pid gone"; fi
    done
}

# SIGTERM to the processes NAMES by their recorded PIDs; wait; SIGKILL what outlives it.
stop_group() {
    local name pid pids=()
    for name in "$@"; do
        [ -f "$DIR/$name.pid" ] || continue
        pid=$(cat "$DIR/$name.pid")
        if ours "$pid"; then
            kill -TERM "$pid"
            pids+=("$pid")
        fi
        rm -f "$DIR/$name.pid"
    done
    [ ${#pids[@]} -gt 0 ] || return 0
    for _ in $(seq 1 200); do
        local alive=0
        for pid in "${pids[@]}"; do kill -0 "$pid" 2>/dev/null && alive=1; done
        [ $alive -eq 0 ] && return 0
        sleep 0.1
    done
    for pid in "${pids[@]}"; do
        if ours "$pid"; then
            echo "local-cluster.sh: pid $pid did not stop in 20 s: SIGKILL" >&2
            kill -KILL "$pid"
        fi
    done
}

stop() {
    local instances=() pidfile
    for pidfile in "$DIR"/local-*.pid; do
        [ -e "$pidfile" ] && instances+=("$(basename "$pidfile" .pid)")
    done
    # Instances first (they checkpoint their sessions), then the routers.
    stop_group "${instances[@]}"
    stop_group router-a router-b
    echo "stopped (logs kept in $DIR)"
}

case $command in
    start) start ;;
    stop) stop ;;
    status) status ;;
    -h|--help|help) usage 0 ;;
    *) echo "local-cluster.sh: unknown command $command" >&2; usage 2 ;;
esac
