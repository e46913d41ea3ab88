#!/usr/bin/env bash
# A one-node Slurm cluster on this machine, to try (and test) deploy/slurm/*.sbatch under a real
# Slurm. Root only; Debian's slurm-wlm and munge (deploy/install-deps.sh installs them).
#
#   bash deploy/slurm/one-node-cluster.sh start     # then: export SLURM_CONF=/run/glissade-slurm/slurm.conf
#   sbatch deploy/slurm/coordinator.sbatch; sbatch --array=1-2 --ntasks=1 deploy/slurm/pool.sbatch
#   bash deploy/slurm/one-node-cluster.sh stop
#
# Everything lives in $GLISSADE_SLURM_DIR (default /run/glissade-slurm): slurm.conf, a munged
# of its own on its own socket and key, state, spool, logs and pid files. Nothing in /etc is
# changed and no system service is started, so a machine's own Slurm or munge is left alone
# (but this cluster uses the standard ports 6817/6818: not beside a real slurmd). Containers
# have no cgroups to give: processes are tracked by their parent ids (proctrack/linuxproc), no
# task binding, no accounting. Jobs share cores (OverSubscribe=FORCE:4): a coordinator and a few
# small pools fit on 2 cores. `start` returns once `sinfo` shows the node idle; `stop` ends the
# daemons, and any jobs, and removes the directory.
set -euo pipefail

dir=${GLISSADE_SLURM_DIR:-/run/glissade-slurm}
conf=$dir/slurm.conf
wait_s=${GLISSADE_SLURM_WAIT:-30}

die() { echo "one-node-cluster: $*" >&2; exit 1; }

[[ $(id -u) -eq 0 ]] || die "run as root (the daemons run as root)"
for tool in munged slurmctld slurmd sinfo; do
  command -v "$tool" >/dev/null || die "'$tool' not found: install slurm-wlm and munge (deploy/install-deps.sh)"
done

# Kills the daemon whose pid is in FILE, waiting up to 10 s for it to go.
stop_daemon() {
  local file=$1 pid
  [[ -s $file ]] || return 0
  pid=$(cat "$file")
  if kill -TERM "$pid" 2>/dev/null; then
    for _ in $(seq 100); do kill -0 "$pid" 2>/dev/null || break; sleep 0.1; done
    kill -KILL "$pid" 2>/dev/null || true
  fi
  rm -f "$file"
}

stop() {
  [[ -d $dir ]] || { echo "one-node-cluster: not running ($dir absent)"; return 0; }
  # Cancel what is left so no job step outlives the cluster, then the daemons.
  if [[ -s $dir/slurmctld.pid ]] && kill -0 "$(cat "$dir/slurmctld.pid")" 2>/dev/null; then
    SLURM_CONF=$conf timeout 10 scancel --user=root --full 2>/dev/null || true
    for _ in $(seq 50); do
      [[ -z $(SLURM_CONF=$conf timeout 5 squeue -h -o %i 2>/dev/null) ]] && break
      sleep 0.2
    done
  fi
  stop_daemon "$dir/slurmd.pid"
  stop_daemon "$dir/slurmctld.pid"
  stop_daemon "$dir/munged.pid"
  rm -rf "$dir"
  echo "one-node-cluster: stopped"
}

start() {
  if [[ -s $dir/slurmctld.pid ]] && kill -0 "$(cat "$dir/slurmctld.pid")" 2>/dev/null; then
    die "already running (slurmctld pid $(cat "$dir/slurmctld.pid")); '$0 stop' first"
  fi
  rm -rf "$dir"
  # munged wants every directory above its socket searchable by all, its key private.
  mkdir -p "$dir"/{state,spool}
  chmod 755 "$dir"
  (umask 077 && dd if=/dev/urandom of="$dir/munge.key" bs=1024 count=1 status=none)
  munged --socket="$dir/munge.socket" --key-file="$dir/munge.key" --pid-file="$dir/munged.pid" \
    --log-file="$dir/munged.log" --seed-file="$dir/munged.seed" ||
    die "munged did not start: $(tail -n 3 "$dir/munged.log" 2>/dev/null)"

  local host cpus mem_mb
  host=$(hostname -s)
  cpus=$(nproc)
  # RealMemory in MB, a little under the total so that slurmd's own check accepts it.
  mem_mb=$(awk '/^MemTotal:/ {print int($2 / 1024 * 0.95)}' /proc/meminfo)
  cat > "$conf" <<EOF
# Written by deploy/slurm/one-node-cluster.sh for this host; removed by its 'stop'.
ClusterName=glissade
SlurmctldHost=$host
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
AuthInfo=socket=$dir/munge.socket
CredType=cred/munge
StateSaveLocation=$dir/state
SlurmdSpoolDir=$dir/spool
SlurmctldPidFile=$dir/slurmctld.pid
SlurmdPidFile=$dir/slurmd.pid
SlurmctldLogFile=$dir/slurmctld.log
SlurmdLogFile=$dir/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
ReturnToService=2
MpiDefault=none
# batch jobs start at once, not after up to 3 s
SchedulerParameters=batch_sched_delay=0
NodeName=$host CPUs=$cpus RealMemory=$mem_mb State=UNKNOWN
PartitionName=main Nodes=$host Default=YES MaxTime=INFINITE OverSubscribe=FORCE:4 State=UP
EOF
  slurmctld -f "$conf" || die "slurmctld did not start: $(tail -n 5 "$dir/slurmctld.log" 2>/dev/null)"
  slurmd -f "$conf" || die "slurmd did not start: $(tail -n 5 "$dir/slurmd.log" 2>/dev/null)"

  local state=""
  for _ in $(seq $((wait_s * 5))); do
    state=$(SLURM_CONF=$conf timeout 5 sinfo -h -n "$host" -o %T 2>/dev/null || true)
    [[ $state == idle ]] && break
    sleep 0.2
  done
  if [[ $state != idle ]]; then
    echo "one-node-cluster: node $host is '${state:-unknown}' after ${wait_s}s, not idle; logs:" >&2
    tail -n 20 "$dir/slurmctld.log" "$dir/slurmd.log" >&2 || true
    stop >&2
    exit 1
  fi
  echo "one-node-cluster: node $host idle ($cpus CPUs, ${mem_mb} MB); export SLURM_CONF=$conf"
}

case ${1:-} in
  start) start ;;
  stop) stop ;;
  *) die "usage: $0 start|stop" ;;
esac
