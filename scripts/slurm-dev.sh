#!/usr/bin/env bash
# A one-node Slurm cluster for development and tests, with every file in DIR:
#
#   scripts/slurm-dev.sh start DIR    # munged, slurmctld and slurmd of this machine; writes
#                                     # DIR/slurm.conf (clients: export SLURM_CONF=DIR/slurm.conf)
#   scripts/slurm-dev.sh stop DIR     # stops those three daemons and nothing else
#   scripts/slurm-dev.sh status DIR   # sinfo and squeue of the cluster
#
# One partition `dev` with this machine as its node (its CPUs and memory), CPUs as the
# consumable resource so that jobs share the node; a munge daemon of its own (key and socket in
# DIR), free ports, no accounting, no cgroups (process tracking by /proc: containers have no
# cgroup delegation). Runs as the user who starts it (root in the test container). `start` on a
# running cluster leaves it as it is. Needs Debian's slurmctld, slurmd, slurm-client and munge
# (scripts/setup.sh --all installs them).
set -euo pipefail

usage() {
  sed -n '2,14p' "$0" | sed 's/^# \{0,1\}//'
  exit 2
}
[ $# -eq 2 ] || usage
cmd=$1
dir=$(realpath -m "$2")
conf="$dir/slurm.conf"
export SLURM_CONF="$conf"
daemons="munged slurmctld slurmd"

pid_of() {  # $1: daemon; prints its pid if it runs
  local f="$dir/run/$1.pid" p
  [ -f "$f" ] || return 1
  p=$(cat "$f" 2>/dev/null || true)
  [ -n "$p" ] && kill -0 "$p" 2>/dev/null && echo "$p"
}

running() {
  local d
  for d in $daemons; do pid_of "$d" >/dev/null || return 1; done
}

stop() {
  local d p left
  for d in $daemons; do
    if p=$(pid_of "$d"); then kill "$p"; fi
  done
  for _ in $(seq 1 40); do
    left=""
    for d in $daemons; do p=$(pid_of "$d") && left="$left $p"; done
    [ -z "$left" ] && break
    sleep 0.25
  done
  for p in $left; do
    if kill -0 "$p" 2>/dev/null; then kill -9 "$p"; fi
  done
  rm -f "$dir"/run/*.pid
}

free_port() {
  /usr/bin/python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'
}

start() {
  local tool
  for tool in munged slurmctld slurmd sinfo sbatch; do
    command -v "$tool" >/dev/null || {
      echo "slurm-dev.sh: $tool not found (install munge slurmctld slurmd slurm-client: bash scripts/setup.sh --all)" >&2
      exit 1
    }
  done
  if [ -f "$conf" ] && running; then
    echo "slurm-dev.sh: the cluster in $dir is already running; clients: export SLURM_CONF=$conf"
    return 0
  fi
  if [ -d "$dir" ] && [ -n "$(ls -A "$dir")" ] && ! [ -f "$conf" ]; then
    echo "slurm-dev.sh: $dir holds other files; give an empty or new directory" >&2
    exit 1
  fi
  stop  # whatever is left of a start that failed half-way
  rm -rf "$dir"
  mkdir -p "$dir"/{run,log,state,spool,munge}
  chmod 700 "$dir/munge"
  # munged refuses a key readable by others.
  dd if=/dev/urandom of="$dir/munge/munge.key" bs=1024 count=1 status=none
  chmod 400 "$dir/munge/munge.key"
  local node cpus mem ctld_port slurmd_port user
  node=$(hostname -s)
  cpus=$(nproc)
  mem=$(awk '/MemTotal/ {print int($2 / 1024 * 0.9)}' /proc/meminfo)
  ctld_port=$(free_port)
  slurmd_port=$(free_port)
  while [ "$slurmd_port" = "$ctld_port" ]; do slurmd_port=$(free_port); done
  user=$(id -un)
  cat >"$conf" <<EOF
ClusterName=hvdbdev
SlurmctldHost=$node(127.0.0.1)
SlurmUser=$user
SlurmdUser=$user
SlurmctldPort=$ctld_port
SlurmdPort=$slurmd_port
AuthType=auth/munge
CredType=cred/munge
AuthInfo=socket=$dir/munge/munge.socket
StateSaveLocation=$dir/state
SlurmdSpoolDir=$dir/spool
SlurmctldPidFile=$dir/run/slurmctld.pid
SlurmdPidFile=$dir/run/slurmd.pid
SlurmctldLogFile=$dir/log/slurmctld.log
SlurmdLogFile=$dir/log/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/none
MpiDefault=none
SwitchType=switch/none
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU
ReturnToService=2
SlurmdTimeout=30
InactiveLimit=0
MinJobAge=300
KillWait=5
MaxArraySize=100001
NodeName=$node NodeAddr=127.0.0.1 CPUs=$cpus RealMemory=$mem State=UNKNOWN
PartitionName=dev Nodes=$node Default=YES MaxTime=INFINITE State=UP OverSubscribe=NO
EOF
  munged --force --socket="$dir/munge/munge.socket" --key-file="$dir/munge/munge.key" \
    --pid-file="$dir/run/munged.pid" --log-file="$dir/log/munged.log" \
    --seed-file="$dir/munge/munged.seed" 2>>"$dir/log/setup.log" || {
    echo "slurm-dev.sh: munged did not start; see $dir/log/setup.log and $dir/log/munged.log" >&2
    stop
    exit 1
  }
  slurmctld -f "$conf" 2>>"$dir/log/setup.log"
  slurmd -f "$conf" -N "$node" 2>>"$dir/log/setup.log"
  # Ready when the node is idle (registered) in the partition.
  for _ in $(seq 1 120); do
    if sinfo -h -N -o '%t' 2>/dev/null | grep -qx 'idle'; then
      echo "slurm-dev.sh: cluster up in $dir (node $node, $cpus CPUs); clients: export SLURM_CONF=$conf"
      return 0
    fi
    sleep 0.5
  done
  echo "slurm-dev.sh: the node did not register within 60 s; logs in $dir/log" >&2
  sinfo -N >&2 || true
  stop
  exit 1
}

case "$cmd" in
  start) start ;;
  stop)
    stop
    echo "slurm-dev.sh: stopped the cluster in $dir"
    ;;
  status)
    if ! [ -f "$conf" ] || ! running; then
      echo "slurm-dev.sh: no cluster runs in $dir (scripts/slurm-dev.sh start $dir)" >&2
      exit 1
    fi
    echo "SLURM_CONF=$conf"
    sinfo
    squeue
    ;;
  *) usage ;;
esac
