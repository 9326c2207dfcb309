#!/usr/bin/env bash
# A real single-node SLURM cluster on this machine, for testing the Snakemake SLURM profile.
#
#   tools/slurm-local.sh start    # writes a minimal slurm.conf, starts munged, slurmctld and slurmd (as root)
#   tools/slurm-local.sh status   # sinfo
#   tools/slurm-local.sh stop     # stops the daemons started by `start` and removes the slurm.conf it wrote
#
# Needs Debian's slurm-wlm and munge packages (`apt-get install slurm-wlm munge`) and root.
# No accounting database: run Snakemake with `--slurm-status-command squeue` (profiles/slurm does).
# State lives in $SLURM_LOCAL_DIR (default /tmp/ddsolve-slurm).
set -euo pipefail
DIR=${SLURM_LOCAL_DIR:-/tmp/ddsolve-slurm}
CONF=/etc/slurm/slurm.conf
MARK="# written by ddsolve tools/slurm-local.sh (removed by its stop)"
cmd=${1:-status}

need() { command -v "$1" >/dev/null 2>&1 || { echo "slurm-local: $1 not found (apt-get install slurm-wlm munge)" >&2; exit 3; }; }

start() {
    need slurmctld; need slurmd; need munged
    [ "$(id -u)" = 0 ] || { echo "slurm-local: must run as root" >&2; exit 3; }
    mkdir -p "$DIR"/{spool/ctld,spool/d,log,run} /etc/slurm /etc/munge /run/munge /var/log/munge /var/lib/munge
    if [ ! -s /etc/munge/munge.key ]; then
        dd if=/dev/urandom bs=1 count=1024 of=/etc/munge/munge.key 2>/dev/null
    fi
    chown -R munge:munge /etc/munge /run/munge /var/log/munge /var/lib/munge 2>/dev/null || true
    chmod 0400 /etc/munge/munge.key
    if ! pgrep -x munged >/dev/null; then          # started here: its pid is recorded for stop
        su -s /bin/sh munge -c munged 2>/dev/null || munged --force
        for _ in 1 2 3 4 5; do [ -s /run/munge/munged.pid ] && break; sleep 0.2; done
        cp /run/munge/munged.pid "$DIR/run/munged.pid" 2>/dev/null || true      # the daemon's own pid file
    fi
    host=$(hostname -s)
    # the online processors, not nproc: it reads OMP_NUM_THREADS and the affinity mask, and a test process
    # with OMP_NUM_THREADS=1 got a 1-CPU node on which a 2-task MPI job waited forever (PartitionConfig)
    cpus=$(getconf _NPROCESSORS_ONLN)
    mem=$(awk '/MemTotal/ {print int($2 / 1024 * 0.9)}' /proc/meminfo)
    if [ -e "$CONF" ] && ! grep -q "$MARK" "$CONF"; then
        echo "slurm-local: $CONF exists and was not written by this script; not touching it" >&2; exit 3
    fi
    cat > "$CONF" <<CONF
$MARK
ClusterName=ddsolve-local
SlurmctldHost=$host
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
StateSaveLocation=$DIR/spool/ctld
SlurmdSpoolDir=$DIR/spool/d
SlurmctldPidFile=$DIR/run/slurmctld.pid
SlurmdPidFile=$DIR/run/slurmd.pid
SlurmctldLogFile=$DIR/log/slurmctld.log
SlurmdLogFile=$DIR/log/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core_Memory
SchedulerType=sched/backfill
ReturnToService=2
MinJobAge=600
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
MpiDefault=none
NodeName=$host CPUs=$cpus RealMemory=$mem State=UNKNOWN
PartitionName=debug Nodes=$host Default=YES MaxTime=INFINITE State=UP
CONF
    pgrep -x slurmctld >/dev/null || slurmctld
    pgrep -x slurmd >/dev/null || slurmd
    for _ in $(seq 1 30); do
        if sinfo -h -o %t 2>/dev/null | grep -qE '^(idle|mix|alloc)'; then sinfo; return 0; fi
        scontrol update nodename="$host" state=resume >/dev/null 2>&1 || true
        sleep 1
    done
    echo "slurm-local: node did not become idle; see $DIR/log" >&2
    sinfo >&2 || true
    exit 1
}

stop() {
    # only the daemons that start started: slurmctld and slurmd write the pid files named in the slurm.conf
    # it wrote, munged's pid was recorded when start launched it (a review: munged was left running, and
    # pkill ended any slurmd or slurmctld on the host)
    for pidfile in "$DIR/run/slurmd.pid" "$DIR/run/slurmctld.pid" "$DIR/run/munged.pid"; do
        if [ -s "$pidfile" ]; then kill "$(cat "$pidfile")" 2>/dev/null || true; fi
        rm -f "$pidfile"
    done
    # Leave the machine as it was: with a slurm.conf but no controller, every `scontrol` (and so
    # every `snakemake` start, whose SLURM executor plugin asks it for MinJobAge) waits ~10 s.
    if [ -e "$CONF" ] && grep -q "$MARK" "$CONF"; then rm -f "$CONF"; fi
}

case "$cmd" in
    start) start ;;
    stop) stop ;;
    status) sinfo ;;
    *) echo "usage: $0 start|status|stop" >&2; exit 2 ;;
esac
