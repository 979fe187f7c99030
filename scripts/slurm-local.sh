#!/usr/bin/env bash
# A one-machine SLURM cluster for the tests: munged, slurmctld and slurmd on this host, with a
# private configuration and state under $SWEPTVOL_SLURM_DIR (default /tmp/sweptvol-slurm).
#   scripts/slurm-local.sh start   # prints `export SLURM_CONF=...` for the caller to eval
#   scripts/slurm-local.sh stop
# Needs root (the daemons run as root here) and Debian's slurm-wlm and munge packages. Exits
# non-zero, saying why, when the cluster does not come up: the tests then fail, never skip.
set -euo pipefail
dir="${SWEPTVOL_SLURM_DIR:-/tmp/sweptvol-slurm}"
conf="$dir/slurm.conf"
host=$(hostname -s)

stop() {
    for pidfile in "$dir/slurmd.pid" "$dir/slurmctld.pid" "$dir/munged.pid"; do
        [ -f "$pidfile" ] || continue
        pid=$(cat "$pidfile")
        kill "$pid" 2>/dev/null || true
        for _ in $(seq 50); do kill -0 "$pid" 2>/dev/null || break; sleep 0.1; done
        kill -9 "$pid" 2>/dev/null || true
        rm -f "$pidfile"
    done
}

start() {
    stop
    rm -rf "$dir"
    mkdir -p "$dir/state" "$dir/spool" "$dir/munge"
    chown munge:munge "$dir/munge"
    chmod 755 "$dir/munge"
    [ -s /etc/munge/munge.key ] || { echo "no /etc/munge/munge.key: install Debian's munge package" >&2; exit 1; }
    cpus=$(nproc)
    mem=$(( $(awk '/MemTotal/ {print $2}' /proc/meminfo) / 1024 - 1024 ))
    cat > "$conf" <<CONF
ClusterName=sweptvol-test
SlurmctldHost=$host
AuthType=auth/munge
AuthInfo=socket=$dir/munge/munge.socket
SlurmUser=root
SlurmdUser=root
SlurmctldPort=16817
SlurmdPort=16818
StateSaveLocation=$dir/state
SlurmdSpoolDir=$dir/spool
SlurmctldPidFile=$dir/slurmctld.pid
SlurmdPidFile=$dir/slurmd.pid
SlurmctldLogFile=$dir/slurmctld.log
SlurmdLogFile=$dir/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU
ReturnToService=2
MpiDefault=none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
JobRequeue=1
SchedulerParameters=defer_batch
MinJobAge=600
NodeName=$host CPUs=$cpus RealMemory=$mem State=UNKNOWN
PartitionName=debug Nodes=ALL Default=YES MaxTime=INFINITE State=UP
CONF
    runuser -u munge -- /usr/sbin/munged --socket="$dir/munge/munge.socket" \
        --pid-file="$dir/munge/munged.pid" --log-file="$dir/munge/munged.log" \
        --seed-file="$dir/munge/munged.seed"
    cp "$dir/munge/munged.pid" "$dir/munged.pid"
    SLURM_CONF="$conf" /usr/sbin/slurmctld
    SLURM_CONF="$conf" /usr/sbin/slurmd
    # Up when the node takes jobs.
    for _ in $(seq 60); do
        if SLURM_CONF="$conf" sinfo -h -o '%t' 2>/dev/null | grep -qE '^(idle|mix|alloc)'; then
            echo "export SLURM_CONF=$conf"
            return 0
        fi
        sleep 0.5
    done
    echo "SLURM did not come up; its logs:" >&2
    tail -n 20 "$dir/slurmctld.log" "$dir/slurmd.log" "$dir/munge/munged.log" >&2 || true
    SLURM_CONF="$conf" sinfo >&2 || true
    exit 1
}

case "${1:-}" in
    start) start ;;
    stop) stop ;;
    *) echo "usage: $0 start|stop" >&2; exit 2 ;;
esac
