#!/usr/bin/env bash
# A one-node SLURM cluster on this machine (slurmctld + slurmd, authenticated by munge), for
# running `saarcor sweep --cluster slurm` without a real cluster, and for its test
# (tests/test_slurm.py). The daemons are started directly (no systemd) as the current user
# (root, for slurmd), with no cgroups: proctrack/linuxproc, task/none.
#
#   scripts/slurm-local.sh start    # write slurm.conf, start munged (if none runs), slurmctld,
#                                   # slurmd; wait until the node is idle
#   scripts/slurm-local.sh status   # exit 0 when this cluster answers and its node is up
#   scripts/slurm-local.sh stop     # cancel its jobs, stop the daemons it started
#   scripts/slurm-local.sh env      # the line to export: SLURM_CONF=<dir>/slurm.conf
#
# Everything lives in $SAARCOR_SLURM_DIR (default /tmp/saarcor-slurm): slurm.conf, the
# controller's state, slurmd's spool, the daemons' logs and pid files, and jobcomp.log (one
# line per finished job: JobId, JobName, JobState, NodeList, ...). The SLURM commands (sbatch,
# squeue, scontrol) find the cluster through SLURM_CONF, so export it (`env`) before using them.
# The node is this host (`hostname -s`) with the CPUs and memory `slurmd -C` reports, in one
# partition `local`. Ports: $SAARCOR_SLURM_PORT (slurmctld, default 6817) and the next one
# (slurmd). Needs the Debian packages slurmctld, slurmd, slurm-client and munge
# (scripts/setup.sh installs them as root where apt-get is available).
set -euo pipefail
DIR=${SAARCOR_SLURM_DIR:-/tmp/saarcor-slurm}
PORT=${SAARCOR_SLURM_PORT:-6817}
CONF="$DIR/slurm.conf"
export SLURM_CONF="$CONF"
MUNGE_KEY=${MUNGE_KEY:-/etc/munge/munge.key}
MUNGE_SOCKET=/run/munge/munge.socket.2

die() { echo "slurm-local: $*" >&2; exit 1; }

need() {
  local missing=()
  for c in slurmctld slurmd sbatch squeue scontrol sinfo scancel munged munge unmunge; do
    command -v "$c" >/dev/null 2>&1 || missing+=("$c")
  done
  [ ${#missing[@]} = 0 ] || die "missing ${missing[*]} (as root: apt-get install slurmctld slurmd slurm-client munge, or scripts/setup.sh)"
}

alive() { [ -f "$1" ] && kill -0 "$(cat "$1")" 2>/dev/null; }

munge_ok() { munge -n 2>/dev/null | unmunge >/dev/null 2>&1; }

start_munge() {
  munge_ok && return 0
  if [ ! -s "$MUNGE_KEY" ]; then
    mkdir -p "$(dirname "$MUNGE_KEY")"
    if command -v mungekey >/dev/null 2>&1; then
      mungekey --create --keyfile="$MUNGE_KEY"
    else
      dd if=/dev/urandom of="$MUNGE_KEY" bs=1 count=1024 2>/dev/null
    fi
    chmod 0400 "$MUNGE_KEY"
  fi
  mkdir -p /run/munge /var/lib/munge /var/log/munge
  local user=root
  if id munge >/dev/null 2>&1 && [ "$(id -u)" = 0 ]; then
    user=munge
    chown munge: "$MUNGE_KEY" "$(dirname "$MUNGE_KEY")" /run/munge /var/lib/munge /var/log/munge
  fi
  if [ "$user" = munge ]; then
    runuser -u munge -- munged --pid-file=/run/munge/munged.pid </dev/null >/dev/null 2>&1
  else
    munged --force --pid-file=/run/munge/munged.pid </dev/null >/dev/null 2>&1
  fi
  cp /run/munge/munged.pid "$DIR/munged.pid"      # ours: `stop` ends it
  for _ in $(seq 50); do munge_ok && return 0; sleep 0.2; done
  die "munged did not answer (log: /var/log/munge/munged.log)"
}

write_conf() {
  local host node
  host=$(hostname -s)
  # the node as slurmd sees it: CPUs, sockets, cores, threads, RealMemory
  node=$(slurmd -C | head -1)
  case "$node" in NodeName=*) ;; *) die "slurmd -C printed no node line: $node" ;; esac
  mkdir -p "$DIR/state" "$DIR/spool"
  cat > "$CONF" <<EOF
# one-node SLURM for this machine, written by scripts/slurm-local.sh
ClusterName=saarcor-local
SlurmctldHost=$host(127.0.0.1)
SlurmctldPort=$PORT
SlurmdPort=$((PORT + 1))
SlurmUser=$(id -un)
SlurmdUser=root
AuthType=auth/munge
StateSaveLocation=$DIR/state
SlurmdSpoolDir=$DIR/spool/%n
SlurmctldPidFile=$DIR/slurmctld.pid
SlurmdPidFile=$DIR/slurmd.pid
SlurmctldLogFile=$DIR/slurmctld.log
SlurmdLogFile=$DIR/slurmd.log
# no cgroups, no systemd
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
MpiDefault=none
SwitchType=switch/none
# no slurmdbd: finished jobs go to a text file
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/filetxt
JobCompLoc=$DIR/jobcomp.log
# one job per CPU; memory is checked against the node's but not reserved
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU
ReturnToService=2
SlurmctldTimeout=30
SlurmdTimeout=30
InactiveLimit=0
KillWait=5
MinJobAge=600
# jobs run at the nice value of the command that submitted them (sbatch under `nice`)
PropagatePrioProcess=1
$node NodeAddr=127.0.0.1 State=UNKNOWN
PartitionName=local Nodes=$host Default=YES MaxTime=INFINITE State=UP
EOF
}

node_up() {
  local st
  st=$(sinfo -h -N -o %T 2>/dev/null | head -1) || return 1
  case "$st" in idle*|mixed*|allocated*|completing*) return 0 ;; *) return 1 ;; esac
}

status() {
  [ -f "$CONF" ] && alive "$DIR/slurmctld.pid" && alive "$DIR/slurmd.pid" && node_up
}

start() {
  need
  if status; then
    echo "slurm-local: already running (SLURM_CONF=$CONF)"
    return 0
  fi
  if alive "$DIR/slurmctld.pid" || alive "$DIR/slurmd.pid"; then
    stop_daemons
  fi
  mkdir -p "$DIR"
  write_conf
  start_munge
  # -i: ignore state saved by an earlier run whose configuration differs; daemons detach
  slurmctld -i -f "$CONF" </dev/null >/dev/null 2>&1 || die "slurmctld failed (log: $DIR/slurmctld.log)"
  slurmd -f "$CONF" </dev/null >/dev/null 2>&1 || die "slurmd failed (log: $DIR/slurmd.log)"
  for _ in $(seq 100); do
    if node_up; then
      echo "slurm-local: running, node $(hostname -s) $(sinfo -h -N -o '%c CPUs, %m MB') (SLURM_CONF=$CONF)"
      return 0
    fi
    sleep 0.3
  done
  sinfo -N -l >&2 || true
  tail -5 "$DIR/slurmctld.log" "$DIR/slurmd.log" >&2 || true
  die "the node did not come up in 30 s (logs in $DIR)"
}

stop_daemons() {   # SIGTERM the daemons this script started, wait up to 10 s, then SIGKILL
  local f pids=()
  for f in "$DIR/slurmd.pid" "$DIR/slurmctld.pid" "$DIR/munged.pid"; do
    if alive "$f"; then
      pids+=("$(cat "$f")")
      kill "${pids[-1]}" 2>/dev/null || true
    fi
    rm -f "$f"
  done
  for _ in $(seq 50); do
    local left=0 p
    for p in "${pids[@]}"; do kill -0 "$p" 2>/dev/null && left=1; done
    [ $left = 0 ] && return 0
    sleep 0.2
  done
  for p in "${pids[@]}"; do kill -9 "$p" 2>/dev/null || true; done
}

stop() {
  if [ -f "$CONF" ] && alive "$DIR/slurmctld.pid"; then
    # cancel every job of this cluster and wait until they are gone (their processes end)
    scancel --full --partition=local 2>/dev/null || true
    for _ in $(seq 50); do
      [ -z "$(squeue -h -t R,CG,PD -o %i 2>/dev/null)" ] && break
      sleep 0.2
    done
  fi
  stop_daemons
  echo "slurm-local: stopped"
}

case "${1:-}" in
  start) start ;;
  stop) stop ;;
  status) if status; then echo "slurm-local: running (SLURM_CONF=$CONF)"; else echo "slurm-local: not running"; exit 1; fi ;;
  env) echo "export SLURM_CONF=$CONF" ;;
  *) echo "usage: $0 start|stop|status|env   (directory: \$SAARCOR_SLURM_DIR, default /tmp/saarcor-slurm)" >&2; exit 2 ;;
esac
