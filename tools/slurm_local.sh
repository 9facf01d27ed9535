#!/usr/bin/env bash
# A one-node Slurm cluster on this machine, for tests that submit real job
# arrays (tests/dataset_slurm.rs). Run as root; no systemd needed.
#   tools/slurm_local.sh install   apt-get install slurm-wlm munge (bounded)
#   tools/slurm_local.sh start     munged, slurmctld, slurmd; waits for an idle node
#   tools/slurm_local.sh stop      stops the three daemons by their pid files
#   tools/slurm_local.sh status    exit 0 when the node answers idle
# Idempotent: start on a running cluster and stop on a stopped one do
# nothing. Every wait is bounded (SLURM_LOCAL_TIMEOUT seconds, default 60);
# a failure prints one line and exits non-zero. It writes
# /etc/slurm/slurm.conf only when that file is absent or its own.
set -euo pipefail

TIMEOUT=${SLURM_LOCAL_TIMEOUT:-60}
CONF=/etc/slurm/slurm.conf
MARK="# written by optistim tools/slurm_local.sh"
CTLD_PID=/run/slurmctld.pid
SLURMD_PID=/run/slurmd.pid
MUNGE_PID=/run/munge/munged.pid

die() { echo "slurm_local: $*" >&2; exit 1; }

alive() { [ -s "$1" ] && kill -0 "$(cat "$1")" 2>/dev/null; }

node_idle() {
  local state
  state=$(timeout 5 sinfo -h -N -o %T 2>/dev/null | head -1) || return 1
  [[ "$state" == idle* || "$state" == mixed* || "$state" == allocated* ]]
}

wait_for() {  # wait_for SECONDS WHAT COMMAND...
  local until=$((SECONDS + $1)) what=$2; shift 2
  until "$@"; do
    [ "$SECONDS" -lt "$until" ] || die "timed out after $TIMEOUT s waiting for $what"
    sleep 0.5
  done
}

install() {
  command -v apt-get >/dev/null || die "no apt-get: install slurm-wlm and munge by hand"
  export DEBIAN_FRONTEND=noninteractive
  timeout 600 apt-get install -y -qq --no-install-recommends slurm-wlm munge >/dev/null \
    || die "apt-get install slurm-wlm munge failed or timed out"
}

write_conf() {
  if [ -e "$CONF" ] && ! grep -qF "$MARK" "$CONF"; then
    die "$CONF exists and is not ours; not touching it"
  fi
  local host cpus mem
  host=$(hostname -s)
  cpus=$(nproc)
  mem=$(awk '/MemTotal/ {m = int($2 / 1024) - 512; print (m > 256 ? m : 256)}' /proc/meminfo)
  mkdir -p /etc/slurm /var/spool/slurmctld /var/spool/slurmd /var/log/slurm
  cat > "$CONF.tmp" <<CONF
$MARK
ClusterName=local
SlurmctldHost=$host
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
StateSaveLocation=/var/spool/slurmctld
SlurmdSpoolDir=/var/spool/slurmd
SlurmctldLogFile=/var/log/slurm/slurmctld.log
SlurmdLogFile=/var/log/slurm/slurmd.log
SlurmctldPidFile=$CTLD_PID
SlurmdPidFile=$SLURMD_PID
ReturnToService=2
MpiDefault=none
NodeName=$host CPUs=$cpus RealMemory=$mem State=UNKNOWN
PartitionName=debug Nodes=$host Default=YES MaxTime=INFINITE State=UP
CONF
  mv "$CONF.tmp" "$CONF"
}

start_munge() {
  alive "$MUNGE_PID" && return 0
  mkdir -p /etc/munge /run/munge /var/log/munge /var/lib/munge
  if [ ! -s /etc/munge/munge.key ]; then
    dd if=/dev/urandom of=/etc/munge/munge.key bs=1024 count=1 status=none
  fi
  chown -R munge:munge /etc/munge /run/munge /var/log/munge /var/lib/munge
  chmod 700 /etc/munge
  chmod 400 /etc/munge/munge.key
  timeout "$TIMEOUT" runuser -u munge -- /usr/sbin/munged || die "munged did not start"
  wait_for "$TIMEOUT" "munge" sh -c 'munge -n | unmunge >/dev/null 2>&1'
}

start() {
  [ "$(id -u)" = 0 ] || die "run as root"
  for c in slurmctld slurmd sbatch sinfo munged; do
    command -v "$c" >/dev/null || [ -x "/usr/sbin/$c" ] || die "$c not installed (tools/slurm_local.sh install)"
  done
  if alive "$CTLD_PID" && alive "$SLURMD_PID" && node_idle; then
    echo "slurm_local: running"; return 0
  fi
  write_conf
  start_munge
  alive "$CTLD_PID" || timeout "$TIMEOUT" slurmctld || die "slurmctld did not start (/var/log/slurm/slurmctld.log)"
  wait_for "$TIMEOUT" "slurmctld" sh -c "timeout 5 scontrol ping 2>/dev/null | grep -q UP"
  alive "$SLURMD_PID" || timeout "$TIMEOUT" slurmd || die "slurmd did not start (/var/log/slurm/slurmd.log)"
  # A node left down or drained by an earlier run returns to service.
  timeout 5 scontrol update nodename="$(hostname -s)" state=resume >/dev/null 2>&1 || true
  wait_for "$TIMEOUT" "an idle node" node_idle
  echo "slurm_local: running ($(timeout 5 sinfo -h -N -o '%N %T %c CPUs'))"
}

stop_one() {  # stop_one PIDFILE NAME
  alive "$1" || return 0
  local pid; pid=$(cat "$1")
  kill "$pid" 2>/dev/null || true
  local until=$((SECONDS + 10))
  while kill -0 "$pid" 2>/dev/null && [ "$SECONDS" -lt "$until" ]; do sleep 0.2; done
  kill -0 "$pid" 2>/dev/null && kill -9 "$pid" 2>/dev/null || true
  echo "slurm_local: stopped $2 ($pid)"
}

stop() {
  stop_one "$SLURMD_PID" slurmd
  stop_one "$CTLD_PID" slurmctld
  stop_one "$MUNGE_PID" munged
}

case "${1:-}" in
  install) install ;;
  start) start ;;
  stop) stop ;;
  status) node_idle || die "no idle Slurm node" ;;
  *) echo "usage: $0 install|start|stop|status" >&2; exit 2 ;;
esac
